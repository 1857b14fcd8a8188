"""The episode arrays of N arms, owned by one object: clock, torques, truth, observation.

`EpisodeState` holds every per-arm array that a batch's control periods change besides
the simulator's state (q, q', theta, theta') and the plant's: step counters and times,
whether an episode runs, the torques (current, previous, the clipped one of the period
being computed, the task's open-loop one), the saturation flags, q'', the reference
q_d .. q_d^(4), the termination codes and reasons, the observation and the sensor delay
line.

Other parts read these arrays; they change them only through the methods here, or in
place through the compiled kernels of a control period
([`kernels`][elastic_gym.envs.kernels]), to which [`packing`][elastic_gym.envs.packing]
hands them. No array is ever rebound (but `reasons`, which no kernel holds), so the
packed kernel arguments stay valid for the batch's lifetime.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from elastic_gym.arms import REFERENCE_KEYS
from elastic_gym.envs.kernels import advance_clock, break_codes, clip_torque

REASONS = np.array(
    [None, "joint limit exceeded", "velocity limit exceeded", "non-finite state"], dtype=object
)
"""Termination reason by code of `break_codes` (0: the physics holds)."""


class EpisodeState:
    """The per-arm episode arrays of a batch of ``n_arms`` arms with ``n_joints`` joints.

    Args:
        n_arms: number of arms N.
        n_joints: number of joints n.
        control_dt: control period (s): time = steps * control_dt.
        max_steps: episode length in control periods (None: episodes are not truncated).
        observation_shapes: shape of one arm's entry of each observation key.
        position_key: the observation key of the encoders (its readings are delayed).
        sensor_delay: the per-arm measurement delay in control periods (N,), read here,
            owned by the plant state (randomization changes it).
        sensor_line: slots of the sensor delay line (1 + the largest delay an arm can
            have).

    Attributes (read by the other parts):
        steps: control periods since each arm's reset (N,), int64.
        time: simulated time of each arm's episode (N,) (s); not a copy.
        running: whether an episode is under way (reset, not ended) (N,).
        torque: the clipped motor torque of the last period (N, n); `previous_torque`
            the one before it.
        clipped: the clipped torque of the period being computed (N, n).
        external: the task's open-loop torque of that period (N, n).
        saturated: whether the last action was clipped (N,).
        ddq: the true q'' at the end of the last period (N, n).
        reference: q_d .. q_d^(4) at each arm's time (N, 5, n).
        codes: the termination codes of the last check (N,) (`REASONS`).
        reasons: why each arm's episode was terminated at the last period (None where it
            was not) (N,), object array (the one array that is rebound: read it here).
        obs: the observation by key, (N, ...) each.
        lines: the sensor delay line of each measured key, (sensor_line, N, ...).
        slot: the slot of the newest reading in the delay line.
        sensor_line: the slots of the delay line.
    """

    def __init__(
        self,
        n_arms: int,
        n_joints: int,
        control_dt: float,
        max_steps: int | None,
        observation_shapes: Mapping[str, tuple[int, ...]],
        position_key: str,
        sensor_delay: np.ndarray,
        sensor_line: int,
    ) -> None:
        N, n = n_arms, n_joints
        self.n_arms, self.control_dt, self.max_steps = N, control_dt, max_steps
        self.steps = np.zeros(N, dtype=np.int64)
        self.time = np.zeros(N)
        self.running = np.zeros(N, dtype=bool)
        self.torque = np.zeros((N, n))
        self.previous_torque = np.zeros((N, n))
        self.clipped = np.zeros((N, n))
        self.external = np.zeros((N, n))
        self.saturated = np.zeros(N, dtype=bool)
        self.ddq = np.zeros((N, n))
        self.reference = np.zeros((N, len(REFERENCE_KEYS), n))
        self.codes = np.zeros(N, dtype=np.int64)
        self.reasons = np.full(N, None, dtype=object)
        self._no_reasons = np.full(N, None, dtype=object)  # never written to
        self._no_arm = np.zeros(N, dtype=bool)
        self.obs = {key: np.zeros((N, *shape)) for key, shape in observation_shapes.items()}
        self.position_key = position_key
        self.sensor_delay = sensor_delay
        self.lines = {
            key: np.zeros((sensor_line, *value.shape))
            for key, value in self.obs.items()
            if key != "reference"
        }
        self.slot = 0
        self.sensor_line = sensor_line

    # ------------------------------------------------------------------ resets
    def begin(self, arms: np.ndarray, torque: np.ndarray) -> None:
        """New episodes of ``arms`` at time 0, holding the motor torques ``torque``
        (len(arms), n) (the torque that keeps their initial state static)."""
        self.steps[arms] = 0
        self.time[:] = self.steps * self.control_dt
        self.running[arms] = True
        self.reasons[arms] = None
        self.saturated[arms] = False
        self.torque[arms] = torque
        self.previous_torque[arms] = self.torque[arms]

    def set_accelerations(self, arms: np.ndarray | slice, ddq: np.ndarray) -> None:
        """q'' of ``arms`` (rows of ``ddq`` in ``arms`` order)."""
        self.ddq[arms] = ddq

    def set_reference(self, arms: np.ndarray | slice, reference: np.ndarray) -> None:
        """q_d .. q_d^(4) of ``arms`` (rows of ``reference`` in ``arms`` order)."""
        self.reference[arms] = reference

    def limit(self, max_steps: int | None) -> None:
        """Truncate episodes after ``max_steps`` control periods (None: never)."""
        self.max_steps = max_steps

    @property
    def length(self) -> int:
        """`max_steps` as `advance_clock` takes it: -1 when episodes are not truncated
        (an int either way: one compiled signature)."""
        return -1 if self.max_steps is None else self.max_steps

    # ------------------------------------------------------------------ a control period
    def truncation(self) -> np.ndarray:
        """A fresh array for a period's truncation flags (the shared False one when
        episodes have no length: nothing writes it)."""
        return self._no_arm if self.max_steps is None else np.empty(self.n_arms, dtype=bool)

    def clip(
        self, command: np.ndarray, external: np.ndarray | None, low: np.ndarray, high: np.ndarray
    ) -> np.ndarray:
        """The period's torque min(max(command + external, low), high) into `clipped`
        and the saturation flags (`clip_torque`); returns `clipped`."""
        clip_torque(command, external, low, high, self.clipped, self.saturated)
        return self.clipped

    def advance(self, stepping: np.ndarray | None, truncated: np.ndarray) -> bool:
        """The end of a period's clock and torques: the stepping arms' step counts
        (``stepping`` None: every arm), the times, ``truncated`` (written when episodes
        have a length), previous <- current <- the clipped torque. Returns whether an arm
        is truncated."""
        ended = advance_clock(
            self.steps, stepping, self.control_dt, self.length, self.time, truncated
        )
        self.previous_torque[:] = self.torque
        self.torque[:] = self.clipped
        return ended

    def next_slot(self) -> None:
        """The delay line's newest slot moves on by one (once per control period)."""
        self.slot = (self.slot + 1) % self.sensor_line

    def termination_reasons(
        self, q, dq, theta, dtheta, lower, upper, max_velocity
    ) -> np.ndarray | None:
        """Why each arm's physics broke (`break_codes` into `codes`; None entries where it
        did not), or None if no arm's."""
        if not break_codes(q, dq, theta, dtheta, lower, upper, max_velocity, self.codes):
            return None
        return self.broken()

    def broken(self) -> np.ndarray:
        """The reasons of the termination codes in `codes` (N,)."""
        return REASONS[self.codes]

    def record(
        self,
        arms: np.ndarray,
        every: bool,
        readings: Mapping[str, np.ndarray],
        first: bool,
        finite: bool,
    ) -> None:
        """The readings of ``arms`` (rows in ``arms`` order; ``every``: ``arms`` is every
        arm in order) through the sensor delay line into the observation, with the
        reference q_d, q_d'.

        ``first``: the first reading of an episode fills the whole delay line; otherwise
        the reading goes to the newest slot. ``finite``: every arm's state is known to be
        finite; otherwise an arm whose reading is not finite keeps its last observation.
        """
        rows = slice(None) if every else arms
        length = self.sensor_line
        if length > 1:
            oldest = (self.slot - self.sensor_delay[arms]) % length
        for key, value in readings.items():
            if length > 1:
                line = self.lines[key]
                if first:
                    line[:, rows] = value
                else:
                    line[self.slot, rows] = value
                value = line[oldest, arms]
            if not finite and not np.isfinite(value).all():  # a broken state keeps the last
                keep = ~np.isfinite(value).all(axis=1)  # reading
                value = np.where(keep[:, None], self.obs[key][rows], value)
            self.obs[key][rows] = value
        self.obs["reference"][rows] = self.reference[rows, :2].reshape(len(arms), -1)

    def conclude(
        self,
        reward: np.ndarray,
        reasons: np.ndarray | None,
        truncated: np.ndarray,
        ended: bool,
        every: bool,
        stepping: np.ndarray,
        termination_reward: float,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(reward, terminated, truncated) of the stepping arms (zero/False elsewhere) from
        the period's reward, termination reasons (None: no arm broke) and truncation; the
        reasons are kept and the ended episodes stop running."""
        if reasons is None:  # the common case: no arm broke its physics
            self.reasons = self._no_reasons
            terminated = self._no_arm
        else:
            terminated = (reasons != None) & stepping  # noqa: E711 - elementwise test
            self.reasons = np.where(stepping, reasons, np.array(None))
            reward = np.where(terminated, termination_reward, reward)
            truncated = truncated & ~terminated
        if not every:
            reward = np.where(stepping, reward, 0.0)
            truncated = truncated & stepping
        if reasons is not None or ended:  # else no episode ended
            self.running &= ~(terminated | truncated)
        return reward, terminated, truncated

    def end(self, arms: np.ndarray) -> None:
        """End the episodes of ``arms`` now (a wrapper terminated them)."""
        self.running[arms] = False

    # ------------------------------------------------------------------ pickling
    ARRAYS = (
        "steps",
        "time",
        "running",
        "torque",
        "previous_torque",
        "saturated",
        "ddq",
        "reference",
        "codes",
    )

    def snapshot(self) -> dict:
        """Copies of the arrays, the observation, the delay line, its slot and the
        reasons: what `restore` takes."""
        return {
            "arrays": {key: getattr(self, key).copy() for key in self.ARRAYS},
            "obs": {key: value.copy() for key, value in self.obs.items()},
            "lines": {key: value.copy() for key, value in self.lines.items()},
            "slot": self.slot,
            "reasons": self.reasons.copy(),
        }

    def restore(self, snapshot: Mapping) -> None:
        """The state of a `snapshot`, copied into the arrays in place."""
        for key, value in snapshot["arrays"].items():
            getattr(self, key)[...] = value
        for key, value in snapshot["obs"].items():
            self.obs[key][...] = value
        for key, value in snapshot["lines"].items():
            self.lines[key][...] = value
        self.slot = snapshot["slot"]
        self.reasons = snapshot["reasons"].copy()
