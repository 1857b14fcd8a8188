"""Wrappers that put a state estimate (or the truth) in place of the sensor observation
of one env: the N = 1 case of the vector wrappers of
[`elastic_gym.observers.vector`][elastic_gym.observers.vector]
(`elastic_gym.single_env`), whose module docstring documents the observation, the
info and the termination on a non-finite estimate.

``ObserverWrapper(env, observer)`` turns the sensor observation into
``{"state": estimate, "reference": (q_d, q_d')}``; ``TrueStateWrapper(env)`` gives the
same layout from the ground truth, so one controller or policy runs unchanged on
estimated or true state. A diverged estimate, or an update that raises a numerical
error, ends the episode (``"non-finite state estimate"``, the error in
``info["observer_error"]``); after an episode has ended, ``step`` needs a ``reset``.
"""

from __future__ import annotations

import functools

import gymnasium as gym
import numpy as np

from elastic_gym.model import RobotModel
from elastic_gym.observers import vector
from elastic_gym.observers.base import Observer
from elastic_gym.single_env import SingleArmWrapper


class ObserverWrapper(SingleArmWrapper[vector.ObserverWrapper], gym.utils.RecordConstructorArgs):
    """Replace the sensor observation by an observer's state estimate.

    Args:
        env: an elastic_gym env (possibly wrapped, sensor observation intact).
        observer: an `Observer` (the wrapper works on its own copy, ``.observer``)
            or a registry name (``"deluca"``, ``"ekf"``, ...).
        initial_estimate: optional initial state estimate passed to ``observer.reset``.
        model: model the observer is designed on when ``observer`` is a name
            (default: the env's nominal model), e.g.
            ``env.unwrapped.model.perturbed(link_mass=1.1)``.
        **options: options of the named observer.
    """

    def __init__(
        self,
        env: gym.Env,
        observer: Observer | str = "deluca",
        initial_estimate: np.ndarray | None = None,
        model: RobotModel | None = None,
        **options,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self,
            observer=observer,
            initial_estimate=initial_estimate,
            model=model,
            _disable_deepcopy=True,
            **options,
        )
        SingleArmWrapper.__init__(
            self,
            env,
            functools.partial(
                vector.ObserverWrapper,
                observer=observer,
                initial_estimate=initial_estimate,
                model=model,
                **options,
            ),
        )
        self.initial_estimate = initial_estimate

    @property
    def observer(self) -> Observer:
        """The wrapper's own observer (a batched one with its ``diagnostics`` of this arm)."""
        working = self.vector.observer
        if isinstance(working, vector.ObserverArray):
            return working.observers[0]
        arm = getattr(working, "arm_diagnostics", {})
        working.diagnostics = {key: np.asarray(value)[0].item() for key, value in arm.items()}
        return working

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.observer.state_names


class TrueStateWrapper(ObserverWrapper):
    """The observation layout of `ObserverWrapper`, filled with the ground truth."""

    def __init__(self, env: gym.Env) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        super().__init__(env, "true")
