"""Wrappers that put a state estimate (or the truth) in place of the sensor observation.

``ObserverWrapper(env, observer)`` turns the sensor observation into
``{"state": estimate, "reference": (q_d, q_d')}``. The observer is fed every sample
and the torque actually applied (after clipping, ``info["torque"]``), and ``info``
gets ``estimate``, ``true_state_vector``, ``estimation_error`` (estimate - truth) and
the observer's ``observer_diagnostics`` (e.g. the condition number of T_A).
``TrueStateWrapper(env)`` gives the same layout from the ground truth, so one
controller or policy runs unchanged on estimated or true state.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from elastic_gym.model import RobotModel
from elastic_gym.observers.base import Observer
from elastic_gym.observers.registry import make_observer


class ObserverWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Replace the sensor observation by an observer's state estimate.

    Args:
        env: an elastic_gym env (possibly wrapped).
        observer: an :class:`Observer` or a registry name (``"deluca"``, ``"ekf"``, ...).
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
            self, observer=observer, initial_estimate=initial_estimate, model=model,
            _disable_deepcopy=True, **options,
        )
        gym.Wrapper.__init__(self, env)
        base = env.unwrapped
        if isinstance(observer, str):
            observer = make_observer(observer, model or base.model, base.control_dt, **options)
        elif options or model is not None:
            raise ValueError("model and observer options apply only when observer is a name")
        self.observer = observer
        self.initial_estimate = initial_estimate
        dim = observer.state_dim
        self.observation_space = spaces.Dict(
            {
                "state": spaces.Box(-np.inf, np.inf, shape=(dim,), dtype=np.float64),
                "reference": env.observation_space["reference"],
            }
        )
        self._estimate = np.zeros(dim)

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.observer.state_names

    def _measurement(self, obs: dict, info: dict) -> dict:
        measurement = dict(obs)
        if "link_acceleration" in self.observer.privileged:
            measurement["link_acceleration"] = info["true_state"]["ddq"]
        if "true_state" in self.observer.privileged:
            measurement["true_state"] = info["true_state"]
        return measurement

    def _truth(self, info: dict) -> np.ndarray:
        truth = info["true_state"]
        if self.observer.elastic:
            return truth["x"]
        return np.concatenate([truth["q"], truth["dq"]])

    def _annotate(self, info: dict) -> dict:
        truth = self._truth(info)
        info["estimate"] = self._estimate.copy()
        info["true_state_vector"] = truth
        info["estimation_error"] = self._estimate - truth
        info["observer_diagnostics"] = dict(self.observer.diagnostics)
        return info

    def _observation(self, obs: dict) -> dict:
        return {"state": self._estimate.copy(), "reference": obs["reference"]}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._estimate = self.observer.reset(self._measurement(obs, info), self.initial_estimate)
        return self._observation(obs), self._annotate(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if info.get("termination_reason"):
            return self._observation(obs), reward, terminated, truncated, info
        estimate = self.observer.update(
            self._measurement(obs, info), info["torque"], self.env.unwrapped.control_dt
        )
        if not np.all(np.isfinite(estimate)):
            info["termination_reason"] = "non-finite state estimate"
            return self._observation(obs), reward, True, truncated, info
        self._estimate = estimate
        return self._observation(obs), reward, terminated, truncated, self._annotate(info)


class TrueStateWrapper(ObserverWrapper):
    """The observation layout of :class:`ObserverWrapper`, filled with the ground truth."""

    def __init__(self, env: gym.Env) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        super().__init__(env, "true")
