"""Observer wrappers for vector envs: the twins of :mod:`elastic_gym.observers.wrappers`.

``ObserverWrapper(envs, "deluca", **options)`` and ``TrueStateWrapper(envs)`` wrap a
vector env of N arms as their single-env twins wrap one env: the observation becomes
``{"state": (N, dim), "reference": (N, 2n)}`` and ``info`` gets ``estimate``,
``true_state_vector``, ``estimation_error`` and ``observer_diagnostics`` with a leading
arm axis. Observers with a batched form (:class:`~elastic_gym.observers.base.BatchedObserver`)
estimate all arms at once; the others run one copy per arm (:class:`ObserverArray`).
Each arm's estimate is the single-env observer's; an arm whose estimate is no longer
finite (or, in an :class:`ObserverArray`, whose update failed numerically) ends its
episode alone ("non-finite state estimate"). Autoresets are followed.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from elastic_gym.arms import arm_view
from elastic_gym.model import RobotModel
from elastic_gym.observers.base import BatchedObserver, Observer
from elastic_gym.observers.wrappers import (
    NON_FINITE_ESTIMATE,
    NON_FINITE_STATE,
    annotate,
    build_observer,
    check_sensor_space,
    checked_estimate,
    guarded_update,
    measurement,
)


class ObserverArray:
    """One copy of a single-arm observer per arm, behind the batched interface."""

    def __init__(self, observer: Observer, n_arms: int) -> None:
        self.observers = [copy.deepcopy(observer) for _ in range(n_arms)]
        first = self.observers[0]
        self.model, self.elastic, self.privileged = first.model, first.elastic, first.privileged
        self.state_dim, self.state_names = first.state_dim, first.state_names
        self._estimates = np.zeros((n_arms, self.state_dim))
        self.arm_diagnostics: dict[str, np.ndarray] = {}

    def _record(self, arms) -> None:
        for i in arms:
            for key, value in self.observers[i].diagnostics.items():
                column = self.arm_diagnostics.setdefault(
                    key, np.zeros(len(self.observers), dtype=np.asarray(value).dtype)
                )
                column[i] = value

    def reset_arms(self, obs: Mapping, arms: np.ndarray, initial_estimate=None) -> np.ndarray:
        rows = (
            None
            if initial_estimate is None
            else np.broadcast_to(initial_estimate, (len(arms), self.state_dim))
        )
        for k, i in enumerate(arms):
            self._estimates[i] = checked_estimate(
                self.observers[i],
                self.observers[i].reset(arm_view(obs, i), None if rows is None else rows[k]),
                "reset",
            )
        self._record(arms)
        return self._estimates[arms].copy()

    def update_arms(
        self, obs: Mapping, torque: np.ndarray, dt: float, arms: np.ndarray | None = None
    ) -> np.ndarray:
        arms = range(len(self.observers)) if arms is None else arms
        for i in arms:  # a numerical error in one arm's observer is that arm's NaN estimate
            self._estimates[i], _ = guarded_update(
                self.observers[i], arm_view(obs, i), torque[i], dt
            )
        self._record(arms)
        return self._estimates.copy()


class ObserverWrapper(gym.vector.VectorWrapper):
    """Replace the sensor observation of every arm by an observer's state estimate.

    Args:
        env: a vector env of elastic_gym arms (``vector_entry_point`` mode).
        observer: an :class:`Observer` (copied: the wrapper owns its observers) or a
            registry name (``"deluca"``, ``"ekf"``, ...).
        initial_estimate: optional initial state estimate of every arm (one vector, or
            one row per arm).
        model: model the observer is designed on when ``observer`` is a name.
        **options: options of the named observer.
    """

    def __init__(
        self,
        env: VectorEnv,
        observer: Observer | str = "deluca",
        initial_estimate: np.ndarray | None = None,
        model: RobotModel | None = None,
        **options,
    ) -> None:
        super().__init__(env)
        base = env.unwrapped
        if not hasattr(base, "batch"):
            raise TypeError(
                "the vector ObserverWrapper needs an elastic_gym vector env "
                "(gym.make_vec(..., vectorization_mode='vector_entry_point'))"
            )
        single = build_observer(base.batch, observer, model, options)
        check_sensor_space(env.single_observation_space, single)
        N = env.num_envs
        self.observer = single if isinstance(single, BatchedObserver) else ObserverArray(single, N)
        self.initial_estimate = initial_estimate
        dim = single.state_dim
        self.single_observation_space = spaces.Dict(
            {
                "state": spaces.Box(-np.inf, np.inf, shape=(dim,), dtype=np.float64),
                "reference": env.single_observation_space["reference"],
            }
        )
        self.observation_space = batch_space(self.single_observation_space, N)
        self._estimates = np.zeros((N, dim))
        self._autoreset = np.zeros(N, dtype=bool)  # arms the env resets at the next step
        self._all = np.ones(N, dtype=bool)

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.observer.state_names

    def _observation(self, obs: Mapping) -> dict:
        return {"state": self._estimates.copy(), "reference": obs["reference"]}

    def _annotate(self, info: dict) -> dict:
        info = annotate(info, self._estimates, self.observer.elastic, self.observer.arm_diagnostics)
        for key in ("estimate", "true_state_vector", "estimation_error", "observer_diagnostics"):
            info[f"_{key}"] = self._all.copy()
        return info

    def _reset_observer(self, obs: Mapping, info: Mapping, arms: np.ndarray) -> None:
        initial = self.initial_estimate
        if initial is not None and np.ndim(initial) == 2:  # one row per arm: those reset
            initial = np.asarray(initial)[arms]
        if len(arms):
            self._estimates[arms] = self.observer.reset_arms(
                measurement(self.observer, obs, info), arms, initial
            )

    def reset(self, *, seed=None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        mask = (options or {}).get("reset_mask", self._all)
        arms = np.flatnonzero(mask)
        self._reset_observer(obs, info, arms)
        self._autoreset[arms] = False
        return self._observation(obs), self._annotate(info)

    def _update(self, obs: Mapping, info: Mapping, arms: np.ndarray) -> np.ndarray:
        """Advance the observer on ``arms``; return the arms whose estimate is not finite."""
        arms = arms[info["termination_reason"][arms] != NON_FINITE_STATE]
        if not len(arms):
            return arms
        estimates = self.observer.update_arms(
            measurement(self.observer, obs, info),
            info["torque"],
            self.env.unwrapped.control_dt,
            arms,
        )
        finite = np.isfinite(estimates[arms]).all(axis=1)
        self._estimates[arms[finite]] = estimates[arms[finite]]
        return arms[~finite]

    def _final_estimates(self, obs: Mapping, info: dict, ended: np.ndarray) -> None:
        """SAME_STEP: estimate the terminal observations of the arms the env has just reset
        (``info["final_obs"]``) before their observers restart."""
        final_obs = {
            key: np.array(
                [
                    info["final_obs"][i][key] if info["_final_obs"][i] else value[i]
                    for i in range(self.num_envs)
                ]
            )
            for key, value in obs.items()
        }
        final_info = info["final_info"]
        diverged = self._update(final_obs, final_info, ended)
        final_info["termination_reason"][diverged] = NON_FINITE_ESTIMATE
        for i in ended:
            info["final_obs"][i] = {
                "state": self._estimates[i].copy(),
                "reference": info["final_obs"][i]["reference"],
            }
        annotate(final_info, self._estimates, self.observer.elastic, self.observer.arm_diagnostics)

    def step(self, actions):
        obs, reward, terminated, truncated, info = self.env.step(actions)
        mode = self.env.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP)
        restarted = np.flatnonzero(self._autoreset)  # reset by the env in this step
        if mode is AutoresetMode.SAME_STEP and np.any(info.get("_final_obs", False)):
            ended = np.flatnonzero(info["_final_obs"])
            self._final_estimates(obs, info, ended)
            restarted = np.union1d(restarted, ended)
        self._reset_observer(obs, info, restarted)
        diverged = self._update(obs, info, np.setdiff1d(np.arange(self.num_envs), restarted))
        if len(diverged):
            terminated = terminated.copy()
            terminated[diverged] = True
            reasons = info["termination_reason"].copy()
            reasons[diverged] = NON_FINITE_ESTIMATE
            info["termination_reason"] = reasons
            info["_termination_reason"] = reasons != None  # noqa: E711
            self.env.unwrapped.end_episodes(diverged)
        if mode is AutoresetMode.NEXT_STEP:
            self._autoreset = terminated | truncated
        else:  # SAME_STEP resets in the step that ends an episode, except ours (next step)
            self._autoreset = np.isin(np.arange(self.num_envs), diverged)
        return self._observation(obs), reward, terminated, truncated, self._annotate(info)


class TrueStateWrapper(ObserverWrapper):
    """The observation layout of :class:`ObserverWrapper`, filled with the ground truth."""

    def __init__(self, env: VectorEnv) -> None:
        super().__init__(env, "true")


__all__ = ["ObserverArray", "ObserverWrapper", "TrueStateWrapper"]
