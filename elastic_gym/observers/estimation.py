"""The estimation loop of the observer wrappers, on its own: an observer and the estimates
of N arms, reset and advanced from measurements and applied torques.

[`Estimator`][elastic_gym.observers.estimation.Estimator] is what
`elastic_gym.observers.vector.ObserverWrapper` (and so the single-env wrapper) runs at
every reset and step, and what `elastic-gym observe` runs on a recorded log: one code
path, so that a log recorded from a simulated run gives the online estimate bit for bit.
A batched observer estimates all arms at once; any other runs one copy per arm
([`ObserverArray`][elastic_gym.observers.estimation.ObserverArray]). An update that
raises a numerical error, or returns a non-finite estimate, marks its arm as diverged
with the reason; other exceptions are bugs and propagate.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from typing import TypeGuard

import numpy as np

from elastic_gym.arms import arm_view
from elastic_gym.observers.base import BatchedObserver, Observer

NUMERICAL_ERRORS = (np.linalg.LinAlgError, FloatingPointError, OverflowError)
NON_FINITE_INPUT = "infs or NaNs"  # numpy's asarray_chkfinite and scipy's checks say so


def numerical_failure(exc: BaseException) -> bool:
    """Whether `exc` is what a diverged estimate makes numpy / scipy raise: a singular
    or indefinite matrix (`LinAlgError`), a floating-point error or overflow, or a
    `ValueError` refusing an array with infs or NaNs. Other exceptions (a
    `ZeroDivisionError` in a user's code, a `TypeError`) are bugs, not divergence."""
    return isinstance(exc, NUMERICAL_ERRORS) or (
        isinstance(exc, ValueError) and NON_FINITE_INPUT in str(exc)
    )


def observer_name(observer: Observer) -> str:
    """`"observer 'ekf' (ExtendedKalmanFilter)"`: how messages name an observer."""
    return f"observer {observer.name or type(observer).__name__!r} ({type(observer).__name__})"


def non_finite_text(observer: Observer, estimate: np.ndarray) -> str:
    """The error of an update that returned a non-finite estimate: the observer and the
    blocks of `state_names` that are not finite."""
    blocks = np.array_split(np.asarray(estimate, dtype=float), len(observer.state_names))
    names = [
        n for n, b in zip(observer.state_names, blocks, strict=True) if not np.isfinite(b).all()
    ]
    return f"{observer_name(observer)}: non-finite {', '.join(names)} after an update"


def checked_estimate(observer: Observer, estimate: object, call: str) -> np.ndarray:
    """`estimate` if it is a numpy array of shape `(observer.state_dim,)`, else a
    `TypeError` / `ValueError` naming the observer, the call and what it returned."""
    who = observer_name(observer)
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


def guarded(update: Callable[[], np.ndarray]) -> tuple[np.ndarray | None, str | None]:
    """`update()` and None, or None and the text of the numerical failure it raised
    (`numerical_failure`); other exceptions propagate."""
    try:
        return update(), None
    except Exception as exc:
        if not numerical_failure(exc):
            raise
        return None, f"{type(exc).__name__}: {exc}"


def guarded_update(
    observer: Observer, obs: Mapping, torque: np.ndarray, dt: float
) -> tuple[np.ndarray, str | None]:
    """`observer.update`, checked (`checked_estimate`); a numerical failure in it gives a
    NaN estimate and the error's text (`guarded`)."""
    estimate, error = guarded(lambda: observer.update(obs, torque, dt))
    if estimate is None:
        return np.full(observer.state_dim, np.nan), error
    return checked_estimate(observer, estimate, "update"), None


def runs_batched(observer: Observer) -> TypeGuard[BatchedObserver]:
    """Whether `observer` estimates all arms at once: a
    [`BatchedObserver`][elastic_gym.observers.base.BatchedObserver] whose single-arm
    `reset` and `update` are its N = 1 case. A subclass that overrides them runs one copy
    per arm (`ObserverArray`), so that its own code is what runs."""
    cls = type(observer)
    return (
        isinstance(observer, BatchedObserver)
        and cls.reset is BatchedObserver.reset
        and cls.update is BatchedObserver.update
    )


class ObserverArray:
    """One copy of a single-arm observer per arm, behind the batched interface."""

    def __init__(self, observer: Observer, n_arms: int) -> None:
        self.observers = [copy.deepcopy(observer) for _ in range(n_arms)]
        first = self.observers[0]
        self.model, self.elastic, self.privileged = first.model, first.elastic, first.privileged
        self.state_dim, self.state_names = first.state_dim, first.state_names
        self._estimates = np.zeros((n_arms, self.state_dim))
        self.errors: list[str | None] = [None] * n_arms  # of each arm's last update
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
        stepped = range(len(self.observers)) if arms is None else arms
        for i in stepped:  # a numerical error in one arm's observer is that arm's NaN estimate
            self._estimates[i], self.errors[i] = guarded_update(
                self.observers[i], arm_view(obs, i), torque[i], dt
            )
        self._record(stepped)
        return self._estimates.copy()


class Estimator:
    """An observer and the estimates of `n_arms` arms (module docstring).

    `observer` is the working observer: the given one if it runs batched, else an
    `ObserverArray` of copies. `estimates` (N, dim) are the arms' latest estimates;
    `errors` (N,) the reason of each arm's divergence in the last update (None: none).
    """

    def __init__(self, observer: Observer, n_arms: int) -> None:
        self.n_arms = n_arms
        self.observer: BatchedObserver | ObserverArray = (
            observer if runs_batched(observer) else ObserverArray(observer, n_arms)
        )
        self.estimates = np.zeros((n_arms, observer.state_dim))
        self.errors = np.full(n_arms, None, dtype=object)

    def arm_observer(self, arm: int) -> Observer:
        """The observer estimating arm `arm` (the batched one, or that arm's copy)."""
        observer = self.observer
        return observer.observers[arm] if isinstance(observer, ObserverArray) else observer

    def reset(self, measured: Mapping, arms: np.ndarray, initial_estimate=None) -> None:
        """Restart the arms `arms` from their measurements (rows of `measured`)."""
        if len(arms):
            self.estimates[arms] = self.observer.reset_arms(measured, arms, initial_estimate)

    def update(self, measured: Mapping, torque: np.ndarray, dt: float, arms: np.ndarray):
        """Advance the arms `arms` by one period in which `torque` (N, n) was applied and
        `measured` was read; return the arms whose estimate is no longer finite (the
        reasons in `errors`). The other arms keep their estimates."""
        self.errors = np.full(self.n_arms, None, dtype=object)
        if not len(arms):
            return arms
        if isinstance(self.observer, ObserverArray):  # guarded arm by arm
            estimates = self.observer.update_arms(measured, torque, dt, arms)
            self.errors[arms] = [self.observer.errors[i] for i in arms]
        else:
            observer = self.observer
            which = None if len(arms) == self.n_arms else arms  # all: the observer's fast path
            batched, error = guarded(lambda: observer.update_arms(measured, torque, dt, which))
            if batched is None:  # a batched observer's error: every arm it was updating
                self.errors[arms] = error
                return arms
            estimates = batched
        return self._accept(estimates, arms)

    def _accept(self, estimates: np.ndarray, arms: np.ndarray) -> np.ndarray:
        """Store the finite rows of `estimates` (of `arms`); return the arms whose row is
        not finite (their reasons in `errors`)."""
        if len(arms) == self.n_arms and np.isfinite(estimates).all():  # the common case
            self.estimates[:] = estimates  # every arm (`arms` sorted, as `update` takes them)
            return arms[:0]
        finite = np.isfinite(estimates[arms]).all(axis=1)
        if finite.all():
            self.estimates[arms] = estimates[arms]
            return arms[:0]
        self.estimates[arms[finite]] = estimates[arms[finite]]
        for i in arms[~finite]:
            if self.errors[i] is None:
                self.errors[i] = non_finite_text(self.arm_observer(i), estimates[i])
        return arms[~finite]

    def run(
        self, measured: Mapping, torques: np.ndarray, dt: float
    ) -> tuple[np.ndarray, int | None]:
        """Advance every arm through T periods: `measured` holds each observation item
        with a leading time axis (T, N, ...), `torques` (T, N, n) the torque of each period.
        Returns the estimates after each period (T', N, dim) and None, or — when an arm's
        estimate stops being finite in period t — the estimates of the periods before it
        and t (the reasons in `errors`, the estimates those of period t - 1). An observer
        with its own `update_sequence` runs the periods in one call (the same numbers as
        one `update_arms` per period); any other one `update` per period."""
        arms = np.arange(self.n_arms)
        observer = self.observer
        if not has_sequence(observer) or not len(torques):
            return self._run_stepwise(measured, torques, dt)
        batched = observer.update_sequence(measured, torques, dt)
        finite = np.isfinite(batched).all(axis=2).all(axis=1)
        self.errors = np.full(self.n_arms, None, dtype=object)
        if finite.all():
            self.estimates[:] = batched[-1]
            return batched, None
        t = int(np.flatnonzero(~finite)[0])
        if t:
            self.estimates[:] = batched[t - 1]
        self._accept(batched[t], arms)
        return batched[:t], t

    def _run_stepwise(self, measured: Mapping, torques: np.ndarray, dt: float):
        """`run` as one `update` per period (what the wrappers do at every step)."""
        arms = np.arange(self.n_arms)
        out = np.empty((len(torques), self.n_arms, self.estimates.shape[1]))
        for t in range(len(torques)):
            diverged = self.update({k: v[t] for k, v in measured.items()}, torques[t], dt, arms)
            if len(diverged):
                return out[:t], t
            out[t] = self.estimates
        return out, None


def has_sequence(observer: BatchedObserver | ObserverArray) -> TypeGuard[BatchedObserver]:
    """Whether `observer` runs many periods in one `update_sequence` call of its own."""
    return (
        isinstance(observer, BatchedObserver)
        and type(observer).update_sequence is not BatchedObserver.update_sequence
    )
