"""The closed loop of a world's arms and the recording of their time series.

Part of the execute stage. [`ClosedLoop`][elastic_gym.evaluation.closed_loop.ClosedLoop]
steps every arm of a [`World`][elastic_gym.evaluation.world.World] one control period at a
time and keeps each arm's status; [`Recorder`][elastic_gym.evaluation.closed_loop.Recorder]
keeps the samples the metrics are computed from;
[`simulate`][elastic_gym.evaluation.closed_loop.simulate] runs the one with the other.
"""

from __future__ import annotations

import numpy as np

from elastic_gym.controllers.base import public_info
from elastic_gym.evaluation.groups import RunGroup
from elastic_gym.evaluation.metrics import ArmSeries
from elastic_gym.evaluation.world import World

STATUS_OK = "ok"


class Recorder:
    """Preallocated time series of the N arms of one world; arm i's samples stop at
    ``lengths[i]`` (its run ended)."""

    def __init__(self, steps: int, n_arms: int, n: int, state_dim: int, elastic: bool) -> None:
        size = steps + 1
        self.time = np.zeros(size)
        self.q, self.q_ref, self.dq_ref, self.torque = (
            np.zeros((size, n_arms, n)) for _ in range(4)
        )
        self.theta = np.zeros((size, n_arms, n)) if elastic else None
        self.error = np.zeros((size, n_arms, state_dim))
        self.saturated = np.zeros((size, n_arms), dtype=bool)
        self.lengths = np.zeros(n_arms, dtype=int)
        self.row = 0
        self._peaks: dict[str, np.ndarray] = {}

    def _track_diagnostics(self, diagnostics: dict, recording: np.ndarray) -> None:
        for key, value in diagnostics.items():
            column = np.asarray(value)
            if column.dtype.kind not in "biuf":
                continue
            peak = self._peaks.setdefault(key, np.full(len(self.lengths), -np.inf))
            np.maximum(peak, np.where(recording, column.astype(float), -np.inf), out=peak)

    @property
    def diagnostics(self) -> list[dict[str, float]]:
        """Per arm: the largest value of each numeric observer diagnostic it recorded."""
        return [
            {key: float(peak[i]) for key, peak in self._peaks.items() if peak[i] > -np.inf}
            for i in range(len(self.lengths))
        ]

    def record(self, info: dict, recording: np.ndarray) -> None:
        """Row ``row`` of every arm; it counts for the ``recording`` arms only."""
        k = self.row
        truth, reference = info["true_state"], info["reference"]
        self.time[k] = info["time"][np.argmax(recording)]  # an ended arm's clock restarted
        self.q[k] = truth["q"]
        self.q_ref[k] = reference["q"]
        self.dq_ref[k] = reference["dq"]
        self.torque[k] = info["torque"]
        self.error[k] = info["estimation_error"]
        self.saturated[k] = info["torque_saturated"]
        if self.theta is not None:
            self.theta[k] = truth["theta"]
        self._track_diagnostics(info.get("observer_diagnostics", {}), recording)
        self.lengths[recording] = k + 1
        self.row = k + 1

    def series(self, state_names: tuple[str, ...]) -> ArmSeries:
        k = self.row
        return ArmSeries(
            self.time[:k],
            self.q[:k],
            self.q_ref[:k],
            self.dq_ref[:k],
            self.torque[:k],
            self.error[:k],
            state_names,
            self.lengths.copy(),
            None if self.theta is None else self.theta[:k],
            self.saturated[:k],
        )


def _public(info: dict) -> dict:
    """The public info of the arms (time and reference, without Gymnasium's masks)."""
    public = public_info(info)
    public["reference"] = {
        key: value for key, value in public["reference"].items() if not key.startswith("_")
    }
    return public


class ClosedLoop:
    """The closed loop of a world's arms: each arm's status, and which arms still run.

    An arm whose episode ends (terminated by the env or the observer wrapper) is no
    longer recorded and gets zero torque (its status: ``"terminated: <reason>"``, with the
    observer's error in parentheses for a non-finite estimate); the env restarts it
    (autoreset) and its controller is reset then, so that it stays finite while its batch
    mates go on.
    Exceptions propagate.
    """

    def __init__(self, world: World, group: RunGroup) -> None:
        self.world = world
        self.group = group
        n_arms = len(group)
        self.statuses = [STATUS_OK] * n_arms
        self.running = np.ones(n_arms, dtype=bool)
        self.returns = np.zeros(n_arms)  # each arm's rewards while it runs
        self._ended = np.zeros(n_arms, dtype=bool)  # restarted by the autoreset next step
        self.info: dict = {}
        self._obs: dict = {}

    def start(self) -> dict:
        """Reset every arm and its controller; returns the info."""
        self.reset()
        self.reset_controllers()
        return self.info

    def reset(self) -> None:
        """Reset every arm with its seed and the reset options (env and observer)."""
        options = self.group.first.reset_options or None
        self._obs, self.info = self.world.wrapped.reset(seed=self.group.seeds, options=options)

    def reset_controllers(self) -> None:
        arms = np.arange(len(self.group))
        self.world.controller.reset_arms(self._obs, _public(self.info), arms)

    def advance(self) -> bool:
        """One control period of every arm; returns whether any arm still runs."""
        controller = self.world.controller
        restarted = np.flatnonzero(self._ended)
        if len(restarted):
            controller.reset_arms(self._obs, _public(self.info), restarted)
        action = np.where(self.running[:, None], controller(self._obs, _public(self.info)), 0.0)
        self._obs, reward, terminated, truncated, self.info = self.world.wrapped.step(action)
        self.returns[self.running] += reward[self.running]
        self._ended = terminated | truncated
        errors = self.info.get("observer_error", [None] * len(self.statuses))
        for i in np.flatnonzero(self.running & self._ended):
            reason = self.info["termination_reason"][i] or "terminated"
            why = f" ({' '.join(errors[i].split())})" if errors[i] else ""
            self.statuses[i] = f"terminated: {reason}{why}"
        self.running &= ~self._ended
        return bool(self.running.any())


def simulate(loop: ClosedLoop, recorder: Recorder, steps: int) -> None:
    """Run the closed loop ``steps`` control periods, recording."""
    with np.errstate(all="ignore"):
        recorder.record(loop.start(), loop.running)
        for _ in range(steps):
            if not loop.advance():
                break
            recorder.record(loop.info, loop.running)
