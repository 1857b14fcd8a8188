"""Wrappers that put a state estimate (or the truth) in place of the sensor observation.

``ObserverWrapper(env, observer)`` turns the sensor observation into
``{"state": estimate, "reference": (q_d, q_d')}``, feeds the observer every sample and the
torque actually applied (``info["torque"]``), and adds ``estimate``, ``true_state_vector``,
``estimation_error`` (estimate - truth) and ``observer_diagnostics`` to ``info`` at every
step. ``TrueStateWrapper(env)`` gives the same layout from the ground truth.
:mod:`elastic_gym.observers.vector` has the twins for vector envs. An estimate that stops
being finite, or an update that fails as numpy / scipy fail on a diverged estimate
(:func:`numerical_failure`), ends the episode (``terminated``, ``"non-finite state
estimate"``, the error in ``info["observer_error"]``); the observation keeps the last
finite estimate. An estimate that is not an array of shape ``(state_dim,)`` is the
observer's bug: a ``TypeError`` / ``ValueError`` naming the observer and the shape.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from elastic_gym.model import RobotModel
from elastic_gym.observers.base import Observer
from elastic_gym.observers.registry import make_observer

NON_FINITE_STATE = "non-finite state"
NON_FINITE_ESTIMATE = "non-finite state estimate"


def build_observer(
    base, observer: Observer | str, model: RobotModel | None, options: dict
) -> Observer:
    """The wrapper's own observer: built by name on ``model`` (default: the env's nominal
    model), or a private copy of a given instance (envs never share an observer)."""
    if isinstance(observer, str):
        return make_observer(observer, model or base.model, base.control_dt, **options)
    if not isinstance(observer, Observer):
        raise TypeError(f"observer must be an Observer or a registry name, got {observer!r}")
    if options or model is not None:
        raise ValueError("model and observer options apply only when observer is a name")
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


def measurement(observer: Observer, obs: Mapping, info: Mapping) -> dict:
    """The sensor observation plus the ground-truth items the observer is privileged to."""
    measured = dict(obs)
    if "link_acceleration" in observer.privileged:
        measured["link_acceleration"] = info["true_state"]["ddq"]
    if "true_state" in observer.privileged:
        measured["true_state"] = info["true_state"]
    return measured


NUMERICAL_ERRORS = (np.linalg.LinAlgError, FloatingPointError, OverflowError)
NON_FINITE_INPUT = "infs or NaNs"  # numpy's asarray_chkfinite and scipy's checks say so


def numerical_failure(exc: BaseException) -> bool:
    """Whether ``exc`` is what a diverged estimate makes numpy / scipy raise: a singular
    or indefinite matrix (``LinAlgError``), a floating-point error or overflow, or a
    ``ValueError`` refusing an array with infs or NaNs. Other exceptions (a
    ``ZeroDivisionError`` in a user's code, a ``TypeError``) are bugs, not divergence."""
    return isinstance(exc, NUMERICAL_ERRORS) or (
        isinstance(exc, ValueError) and NON_FINITE_INPUT in str(exc)
    )


def checked_estimate(observer: Observer, estimate: object, call: str) -> np.ndarray:
    """``estimate`` if it is a numpy array of shape ``(observer.state_dim,)``, else a
    ``TypeError`` / ``ValueError`` naming the observer, the call and what it returned."""
    who = f"observer {observer.name or type(observer).__name__!r} ({type(observer).__name__})"
    if not isinstance(estimate, np.ndarray):
        raise TypeError(
            f"{who}: {call} returned a {type(estimate).__name__}, expected a numpy array "
            f"of shape ({observer.state_dim},)"
        )
    if estimate.shape != (observer.state_dim,):
        raise ValueError(
            f"{who}: {call} returned an estimate of shape {estimate.shape}, expected "
            f"({observer.state_dim},) (state {observer.state_names})"
        )
    return estimate


def guarded_update(
    observer: Observer, obs: Mapping, torque: np.ndarray, dt: float
) -> tuple[np.ndarray, str | None]:
    """``observer.update``, checked (:func:`checked_estimate`); a numerical failure in it
    (:func:`numerical_failure`) gives a NaN estimate and the error's text (the episode
    ends, see the module doc)."""
    try:
        estimate = observer.update(obs, torque, dt)
    except Exception as exc:
        if not numerical_failure(exc):
            raise
        return np.full(observer.state_dim, np.nan), f"{type(exc).__name__}: {exc}"
    return checked_estimate(observer, estimate, "update"), None


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
    info["estimation_error"] = estimate - truth
    info["observer_diagnostics"] = dict(diagnostics)
    return info


class ObserverWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Replace the sensor observation by an observer's state estimate.

    Args:
        env: an elastic_gym env (possibly wrapped, sensor observation intact).
        observer: an :class:`Observer` (the wrapper works on its own copy, ``.observer``)
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
        gym.Wrapper.__init__(self, env)
        self.observer = build_observer(env.unwrapped, observer, model, options)
        check_sensor_space(env.observation_space, self.observer)
        self.initial_estimate = initial_estimate
        dim = self.observer.state_dim
        self.observation_space = spaces.Dict(
            {
                "state": spaces.Box(-np.inf, np.inf, shape=(dim,), dtype=np.float64),
                "reference": env.observation_space["reference"],
            }
        )
        self._estimate = np.zeros(dim)
        self._needs_reset = True

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.observer.state_names

    def _observation(self, obs: dict) -> dict:
        return {"state": self._estimate.copy(), "reference": obs["reference"]}

    def _annotate(self, info: dict) -> dict:
        return annotate(info, self._estimate, self.observer.elastic, self.observer.diagnostics)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._estimate = checked_estimate(
            self.observer,
            self.observer.reset(measurement(self.observer, obs, info), self.initial_estimate),
            "reset",
        )
        self._needs_reset = False
        return self._observation(obs), self._annotate(info)

    def step(self, action):
        if self._needs_reset:
            raise RuntimeError("call reset() before step() (and after an episode has ended)")
        obs, reward, terminated, truncated, info = self.env.step(action)
        if info.get("termination_reason") != NON_FINITE_STATE:
            estimate, error = guarded_update(
                self.observer,
                measurement(self.observer, obs, info),
                info["torque"],
                self.env.unwrapped.control_dt,
            )
            if np.all(np.isfinite(estimate)):
                self._estimate = estimate
            else:
                info["termination_reason"] = NON_FINITE_ESTIMATE
                if error is not None:
                    info["observer_error"] = error
                terminated = True
        self._needs_reset = terminated or truncated
        return self._observation(obs), reward, terminated, truncated, self._annotate(info)


class TrueStateWrapper(ObserverWrapper):
    """The observation layout of :class:`ObserverWrapper`, filled with the ground truth."""

    def __init__(self, env: gym.Env) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        super().__init__(env, "true")
