"""A policy on the env's own observation (no spec), as the comparison's controller runs it
on N arms: a callable ``obs -> action`` or an object with stable-baselines3's ``predict``.

Every ``decimation`` control periods an arm's policy gets that arm's observation (its
``state`` and ``reference``, or the raw sensors), after ``preprocess(obs, info)`` and the
``normalization``'s ``normalize_obs``, and its action is held in between. The action
a becomes the torque ``torque_limit * clip(a, -1, 1)`` (``scale_actions``), a itself
(not scaled), or with a ``residual`` base the base's torque plus
``residual_scale * torque_limit * rho(a)`` (rho the
[`deadzone`][elastic_gym.policy.actions.deadzone]; Residual Policy Learning, Silver et
al. 2018). Each arm has its own recurrent state, call count and held action, and the
policy is called once per acting arm; the residual base runs as one vector controller.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from elastic_gym.arms import arm_view
from elastic_gym.controllers.vector import ControllerTwin, make_vector_controller
from elastic_gym.policy.actions import residual_torque


class CallableLaw:
    """The loop of the module docstring for the arms of ``twin`` (a
    [`VectorPolicy`][elastic_gym.policy.controller.VectorPolicy] whose controller runs a
    callable or an SB3-like model)."""

    def __init__(self, twin: ControllerTwin[Any]) -> None:
        c = twin.controller
        self.twin, self.c = twin, c
        N = twin.n_arms
        self.base = (
            None
            if c.residual is None
            else make_vector_controller(c.residual, twin.model, twin.dt, N)
        )
        self._states: list = [None] * N
        self._episode_start = np.ones(N, dtype=bool)
        self._calls = np.zeros(N, dtype=np.int64)
        self._held = np.zeros((N, twin.n))

    @property
    def diagnostics(self) -> dict[str, np.ndarray]:
        """None: a callable's actions are not checked against bounds."""
        return {}

    def reset_arms(self, obs: Mapping, info: Mapping, arms: np.ndarray) -> None:
        for i in arms:
            self._states[i] = None
        self._episode_start[arms] = True
        self._calls[arms] = 0
        if self.base is not None:
            self.base.reset_arms(obs, info, arms)

    def act(self, i: int, obs: Mapping, info: Mapping) -> np.ndarray:
        """The raw policy output (n,) of arm i for its own observation and info."""
        c, n = self.c, self.twin.n
        policy_obs = c.preprocess(obs, info) if c.preprocess is not None else obs
        if c.normalization is not None:
            policy_obs = c.normalization.normalize_obs(policy_obs)
        if c.predicts:
            action, self._states[i] = c.policy.predict(
                policy_obs,
                state=self._states[i],
                episode_start=self._episode_start[i : i + 1].copy(),
                deterministic=c.deterministic,
            )
            self._episode_start[i] = False
        else:
            action = c.policy(policy_obs)
        action = np.asarray(action, dtype=float)
        if action.size != n or not np.all(np.isfinite(action)):
            raise ValueError(f"policy must return {n} finite numbers, got {action!r}")
        return action.reshape(n)

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        c = self.c
        for arm in np.flatnonzero(self._calls % c.decimation == 0):  # acts at 1/(decimation dt)
            i = int(arm)
            self._held[i] = self.act(i, arm_view(obs, i), arm_view(info, i))
        self._calls += 1
        action = np.clip(self._held, -1.0, 1.0)
        if self.base is not None:
            correction = residual_torque(
                self._held, c.torque_limit, c.residual_scale, c.residual_deadzone
            )
            return self.base(obs, info) + correction
        if c.scale_actions:
            return c.torque_limit * action
        return self._held.copy()
