"""Observer wrappers for vector envs: the twins of
[`elastic_gym.observers.wrappers`][elastic_gym.observers.wrappers].

``ObserverWrapper(envs, "deluca", **options)`` and ``TrueStateWrapper(envs)`` wrap a vector env of N
arms as their single-env twins wrap one env: the observation becomes ``{"state": (N, dim),
"reference": (N, 2n)}`` and ``info`` gets ``estimate``, ``true_state_vector``, ``estimation_error``
and ``observer_diagnostics`` with a leading arm axis. Observers with a batched form
([`BatchedObserver`][elastic_gym.observers.base.BatchedObserver]) estimate all arms at once; the
others run one copy per arm (`ObserverArray`). Each arm's estimate is the single-env observer's; an
arm whose estimate is no longer finite (or, in an `ObserverArray`, whose update failed numerically)
ends its episode alone: ``info["termination_reason"]`` "non-finite state estimate" and
``info["observer_error"]`` why (the numerical error, or the blocks of the estimate that are not
finite). Autoresets are followed. ``SensorWrapper(envs)`` (raw sensors as the state source) keeps
the sensor observation and adds the same ``info`` with an empty estimate.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import cast

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from elastic_gym.arms import elastic_base
from elastic_gym.model import RobotModel
from elastic_gym.observers.base import BatchedObserver, Observer
from elastic_gym.observers.estimation import Estimator, ObserverArray, runs_batched
from elastic_gym.observers.registry import make_observer
from elastic_gym.observers.sensors import RawSensors
from elastic_gym.validation import only_when

NON_FINITE_STATE = "non-finite state"
NON_FINITE_ESTIMATE = "non-finite state estimate"


def build_observer(
    base, observer: Observer | str, model: RobotModel | None, options: dict
) -> Observer:
    """The wrapper's own observer: built by name on ``model`` (default: the env's nominal
    model), or a private copy of a given instance (envs never share an observer)."""
    named = isinstance(observer, str)
    only_when(named, {"model": model, "observer options": options}, "observer is a name")
    if isinstance(observer, str):
        return make_observer(observer, model or base.model, base.control_dt, **options)
    if not isinstance(observer, Observer):
        raise TypeError(f"observer must be an Observer or a registry name, got {observer!r}")
    own = observer.model.spec
    if own.name != base.robot.name or own.n_joints != base.robot.n_joints:
        raise ValueError(
            f"the observer was built on the model of robot {own.name!r}, "
            f"the env simulates {base.robot.name!r}"
        )
    return copy.deepcopy(observer)


def check_sensor_space(space: spaces.Space, observer: Observer) -> None:
    """The wrapped env must still give the sensor observation (a Dict)."""
    key = "motor_position" if observer.elastic else "link_position"
    if not isinstance(space, spaces.Dict) or key not in space.spaces:
        raise ValueError(
            f"ObserverWrapper needs the env's sensor observation (a Dict with {key!r}), got "
            f"{space}: put the observer wrapper below observation wrappers such as "
            "FlattenObservation"
        )


def measurement(observer: Observer | ObserverArray, obs: Mapping, info: Mapping) -> dict:
    """The sensor observation plus the ground-truth items the observer is privileged to."""
    measured = dict(obs)
    if "link_acceleration" in observer.privileged:
        measured["link_acceleration"] = info["true_state"]["ddq"]
    if "true_state" in observer.privileged:
        measured["true_state"] = info["true_state"]
    return measured


def true_state_vector(info: Mapping, elastic: bool) -> np.ndarray:
    """The true state in the observer's layout (works for one arm and for a batch)."""
    truth = info["true_state"]
    if elastic:
        return np.asarray(truth["x"])
    return np.concatenate([truth["q"], truth["dq"]], axis=-1)


def annotate(info: dict, estimate: np.ndarray, elastic: bool, diagnostics: dict) -> dict:
    """Add ``estimate``, ``true_state_vector``, ``estimation_error``, ``observer_diagnostics``."""
    truth = true_state_vector(info, elastic)
    info["estimate"] = estimate.copy()
    info["true_state_vector"] = truth
    # raw sensors estimate nothing: their error is as empty as their estimate
    info["estimation_error"] = estimate - truth if estimate.shape[-1] else estimate.copy()
    info["observer_diagnostics"] = dict(diagnostics)
    return info


class ObserverWrapper(gym.vector.VectorWrapper):
    """Replace the sensor observation of every arm by an observer's state estimate.

    Args:
        env: a vector env of elastic_gym arms (``vector_entry_point`` mode).
        observer: an `Observer` (copied: the wrapper owns its observers) or a
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
        base = elastic_base(env, "the vector ObserverWrapper")
        single = build_observer(base.batch, observer, model, options)
        check_sensor_space(env.single_observation_space, single)
        N = env.num_envs
        self._base = base
        self.estimator = Estimator(single, N)  # the estimation loop, shared with logs
        self.observer: BatchedObserver | ObserverArray = self.estimator.observer
        self.initial_estimate = initial_estimate
        dim = single.state_dim
        self.single_observation_space = spaces.Dict(
            {
                "state": spaces.Box(-np.inf, np.inf, shape=(dim,), dtype=np.float64),
                "reference": cast(spaces.Dict, env.single_observation_space)["reference"],
            }
        )
        self.observation_space = batch_space(self.single_observation_space, N)
        self._estimates = self.estimator.estimates  # (N, dim), updated in place
        self._autoreset = np.zeros(N, dtype=bool)  # arms the env resets at the next step
        self._all = np.ones(N, dtype=bool)
        self._every = np.arange(N)  # np.flatnonzero(self._all)

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
            self.estimator.reset(measurement(self.observer, obs, info), arms, initial)

    def reset(self, *, seed=None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        mask = (options or {}).get("reset_mask", self._all)
        arms = np.flatnonzero(mask)
        self._reset_observer(obs, info, arms)
        self._autoreset[arms] = False
        return self._observation(obs), self._annotate(info)

    def _update(self, obs: Mapping, info: Mapping, arms: np.ndarray) -> np.ndarray:
        """Advance the observer on ``arms`` (those whose state is still finite); return the
        arms whose estimate is not finite (the reasons in ``self._errors``)."""
        reasons = info["termination_reason"]
        every = len(arms) == len(reasons)  # all arms, in order (`step`'s arms are sorted)
        arms = arms[(reasons if every else reasons[arms]) != NON_FINITE_STATE]
        measured = measurement(self.observer, obs, info) if len(arms) else obs
        return self.estimator.update(measured, info["torque"], self._base.control_dt, arms)

    @property
    def _errors(self) -> np.ndarray:
        """Why each arm diverged in the last update (None: it did not)."""
        return self.estimator.errors

    def _arm_observer(self, arm: int) -> Observer:
        return self.estimator.arm_observer(arm)

    def _mark(self, info: dict, diverged: np.ndarray) -> None:
        """``info["termination_reason"]`` of the ``diverged`` arms: ``NON_FINITE_ESTIMATE``,
        and ``info["observer_error"]``: why (`_update`), None for the other arms."""
        reasons = info["termination_reason"].copy()
        reasons[diverged] = NON_FINITE_ESTIMATE
        errors = np.full(self.num_envs, None, dtype=object)
        errors[diverged] = self._errors[diverged]
        info["termination_reason"], info["observer_error"] = reasons, errors
        info["_termination_reason"] = reasons != None  # noqa: E711
        info["_observer_error"] = errors != None  # noqa: E711

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
        if len(diverged):
            self._mark(final_info, diverged)
        for i in ended:
            info["final_obs"][i] = {
                "state": self._estimates[i].copy(),
                "reference": info["final_obs"][i]["reference"],
            }
        annotate(final_info, self._estimates, self.observer.elastic, self.observer.arm_diagnostics)

    def _terminate(self, diverged: np.ndarray, terminated: np.ndarray, info: dict) -> np.ndarray:
        """End the episodes of the ``diverged`` arms (non-finite estimate): ``terminated``
        and ``info["termination_reason"]`` say so (``info["observer_error"]``: why, see
        `_mark`), and the env resets them like any ended episode."""
        if not len(diverged):
            return terminated
        terminated = terminated.copy()
        terminated[diverged] = True
        self._mark(info, diverged)
        self._base.end_episodes(diverged)
        return terminated

    def step(self, actions):
        obs, reward, terminated, truncated, info = self.env.step(actions)
        mode = self.env.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP)
        restarted = self._autoreset.copy()  # arms reset by the env in this step
        if mode is AutoresetMode.SAME_STEP and np.any(info.get("_final_obs", False)):
            ended = np.flatnonzero(info["_final_obs"])
            self._final_estimates(obs, info, ended)
            restarted[ended] = True
        if restarted.any():
            self._reset_observer(obs, info, np.flatnonzero(restarted))
            diverged = self._update(obs, info, np.flatnonzero(~restarted))
        else:  # the common step: every arm advances
            diverged = self._update(obs, info, self._every)
        terminated = self._terminate(diverged, terminated, info)
        if mode is AutoresetMode.NEXT_STEP:
            self._autoreset = terminated | truncated
        else:  # SAME_STEP resets in the step that ends an episode, except ours (next step)
            self._autoreset = np.zeros(self.num_envs, dtype=bool)
            self._autoreset[diverged] = True
        return self._observation(obs), reward, terminated, truncated, self._annotate(info)


class TrueStateWrapper(ObserverWrapper):
    """The observation layout of `ObserverWrapper`, filled with the ground truth."""

    def __init__(self, env: VectorEnv) -> None:
        super().__init__(env, "true")


class SensorWrapper(ObserverWrapper):
    """Raw sensors as the state source: the sensor observation of every arm is kept as it
    is (no ``state``), and ``info`` gets the wrapper's entries with an empty estimate
    (`RawSensors`), so that a loop on raw sensors
    runs where a loop on an observer does; nothing of the ground truth is read."""

    def __init__(self, env: VectorEnv) -> None:
        base = elastic_base(env, "the SensorWrapper")
        super().__init__(env, RawSensors(base.model, base.control_dt))
        self.single_observation_space = env.single_observation_space
        self.observation_space = env.observation_space

    def _observation(self, obs: Mapping) -> dict:
        return dict(obs)

    def _final_estimates(self, obs: Mapping, info: dict, ended: np.ndarray) -> None:
        """SAME_STEP: the terminal observations stay the sensors' (nothing to estimate)."""
        final = info["final_info"]
        annotate(final, self._estimates, self.observer.elastic, self.observer.arm_diagnostics)


__all__ = [
    "NON_FINITE_ESTIMATE",
    "NON_FINITE_STATE",
    "Estimator",
    "ObserverArray",
    "ObserverWrapper",
    "SensorWrapper",
    "TrueStateWrapper",
    "runs_batched",
    "true_state_vector",
]
