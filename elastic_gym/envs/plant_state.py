"""What changes in the simulated plants while a batch runs: the per-reset draws of
``randomize`` and of random torque pulses (from each arm's plant stream), the payload
changes, the actuator delay line and ``info["plant"]``.

Everything here acts on the simulated plant only; the nominal model never sees it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from elastic_gym.envs.arm_config import ArmSettings
from elastic_gym.envs.disturbances import TorquePulses, given_pulses, random_pulses
from elastic_gym.envs.randomization import PATHS, draw, plant_stream, with_values

if TYPE_CHECKING:
    from elastic_gym.envs.batch import ArmBatch


class PlantState:
    """The per-arm plant state of an :class:`~elastic_gym.envs.batch.ArmBatch`."""

    def __init__(self, batch: ArmBatch) -> None:
        self.batch = batch
        N, n = batch.n_arms, batch.n_joints
        settings, ranges = batch.settings, batch.ranges
        self.pulses = TorquePulses(N, n)
        highs = [s.actuator_delay for s in settings] + [
            int(r["actuator_delay"].maximum) for r in ranges if "actuator_delay" in r
        ]
        self._line = 1 + max(highs)
        self._commands = np.zeros((self._line, N, n))
        self._slot = 0
        self._arms = np.arange(N)
        self.payload_mass = np.zeros(N)
        self._change_time = np.full(N, np.inf)
        self._changes = any(s.payload is not None and s.payload.change for s in settings)
        self._stream = [
            bool(r) or (s.pulses is not None and s.pulses.random is not None)
            for s, r in zip(settings, ranges, strict=True)
        ]
        paths = [p for p in PATHS if any(p in r for r in ranges)]
        self.drawn = {path: np.full(N, np.nan) for path in paths}
        self._arm_values: dict[int, dict] = {}  # info's plain values of one arm, by arm
        for arm, arm_settings in enumerate(settings):
            self._set_payload(arm, arm_settings, initial=True)
            pulses = arm_settings.pulses
            if pulses is not None and pulses.random is None:
                self.pulses.set(arm, *given_pulses(pulses, batch.torque_limit))

    # ------------------------------------------------------------------ resets
    def reset(self, arms: np.ndarray) -> None:
        """New episodes of ``arms``: their draws (plant stream), initial payloads."""
        batch = self.batch
        self._arm_values.clear()
        for arm in arms:
            if self._stream[arm] and batch._plant_sources[arm] is not batch.rngs[arm]:
                batch._plant_sources[arm] = batch.rngs[arm]
                batch.plant_rngs[arm] = plant_stream(batch.rngs[arm])
            rng = batch.plant_rngs[arm]
            if batch.ranges[arm]:
                values = draw(batch.ranges[arm], rng)
                self.apply(arm, batch.resolver.settings(with_values(batch.arm_kwargs[arm], values)))
                for path, value in values.items():
                    self.drawn[path][arm] = value
            else:
                self._set_payload(arm, batch.settings[arm])
            pulses = batch.settings[arm].pulses
            if pulses is not None and pulses.random is not None:
                self.pulses.set(arm, *random_pulses(pulses.random, rng, batch.torque_limit))

    def apply(self, arm: int, settings: ArmSettings) -> None:
        """Give arm ``arm`` the plant and sensors of ``settings``."""
        batch = self.batch
        self._arm_values.clear()
        batch.settings[arm] = settings
        batch.sim.plants.set(arm, batch.resolver.plant_model(settings))
        batch.sim.set_link_scaling(arm, settings.scaling)
        self._set_payload(arm, settings, initial=True)
        batch.encoder.set(arm, *settings.encoder)
        batch.accelerometer_array.set(arm, settings.accelerometer)
        batch.sensor_delay[arm] = settings.sensor_delay
        batch.actuator_delay[arm] = settings.actuator_delay

    def _set_payload(self, arm: int, settings: ArmSettings, initial: bool = False) -> None:
        """The configured initial payload of ``arm`` (PyBullet and the plant model; the model
        is rebuilt only when the mass changed or ``initial``)."""
        payload = settings.payload
        if payload is None:
            return
        batch = self.batch
        self._arm_values.clear()
        if initial or self.payload_mass[arm] != payload.mass:
            if not initial:
                batch.sim.plants.set(arm, batch.resolver.plant_model(settings))
            batch.sim.set_payload_mass(arm, payload.mass)
        self.payload_mass[arm] = payload.mass
        self._change_time[arm] = np.inf if payload.change is None else payload.change.time
        self._changes = self._changes or payload.change is not None

    def reset_commands(self, arms: np.ndarray, torque: np.ndarray) -> None:
        """Fill the actuator delay line of ``arms`` with their reset torque (rows)."""
        if self._line > 1:
            self._commands[:, arms] = torque

    # ------------------------------------------------------------------ steps
    def delayed(self, command: np.ndarray) -> np.ndarray:
        """The torques reaching the motors now: each arm's command of actuator_delay
        control periods ago (the newest command enters the line)."""
        if self._line == 1:
            return command
        self._slot = (self._slot + 1) % self._line
        self._commands[self._slot] = command
        return self._commands[(self._slot - self.batch.actuator_delay) % self._line, self._arms]

    def before_step(self, time: np.ndarray) -> np.ndarray | None:
        """Apply the payload changes due at ``time`` (N,), the start of the control period;
        returns the period's link torque pulses (N, n) or None."""
        due = time >= self._change_time if self._changes else None
        if due is not None and due.any():
            batch = self.batch
            self._arm_values.clear()
            for arm in np.flatnonzero(due).tolist():
                mass = batch.settings[arm].payload.change.mass
                batch.sim.plants.set(arm, batch.resolver.plant_model(batch.settings[arm], mass))
                batch.sim.set_payload_mass(arm, mass)
                self.payload_mass[arm] = mass
                self._change_time[arm] = np.inf
        return self.pulses.torque(time)

    # ------------------------------------------------------------------ outputs
    def info(self, arms) -> dict:
        """``info["plant"]`` of ``arms`` (an int: one arm's plain values)."""
        if isinstance(arms, (int, np.integer)):
            return self._one_arm_info(int(arms))
        out = {path: values[arms].copy() for path, values in self.drawn.items()}
        out["actuator_delay"] = self.batch.actuator_delay[arms].copy()
        out["payload.mass"] = self.payload_mass[arms].copy()  # the current mass
        out["torque_pulse"] = self.pulses.current[arms].copy()
        self._pulse_schedule(arms, out)
        return out

    def _one_arm_info(self, k: int) -> dict:
        """:meth:`info` of arm ``k``; its plain values change only at a reset or a payload
        change, so they are kept between steps (a dict copy costs less than reading them)."""
        values = self._arm_values.get(k)
        if values is None:
            values = {path: drawn[k].item() for path, drawn in self.drawn.items()}
            values["actuator_delay"] = int(self.batch.actuator_delay[k])
            values["payload.mass"] = float(self.payload_mass[k])  # the current mass
            self._arm_values[k] = values
        out = values.copy()
        out["torque_pulse"] = self.pulses.current[k].copy()
        self._pulse_schedule(k, out)
        return out

    def _pulse_schedule(self, arms, out: dict) -> None:
        """The torque pulses' times, durations and amplitudes of ``arms`` into ``out`` (NaN
        for unused slots), where the batch has pulses."""
        pulses = self.pulses
        if pulses.start.shape[1]:
            unused = ~np.isfinite(pulses.start[arms])
            out["torque_pulses.times"] = np.where(unused, np.nan, pulses.start[arms])
            out["torque_pulses.durations"] = np.where(
                unused, np.nan, pulses.end[arms] - pulses.start[arms]
            )
            out["torque_pulses.amplitudes"] = np.where(
                unused[..., None], np.nan, pulses.amplitude[arms]
            )

    def __getstate__(self) -> dict:
        """The state without the batch and without the kept info values (read again)."""
        return {k: v for k, v in vars(self).items() if k not in ("batch", "_arm_values")}
