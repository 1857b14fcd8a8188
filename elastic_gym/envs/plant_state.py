"""What changes in the simulated plants while a batch runs, owned by one object.

`PlantState` holds each arm's settings (its plant and sensors, `per_arm` merged in) and
what changes them: the per-reset draws of `randomize` and of random torque pulses (from
each arm's plant stream, [`elastic_gym.envs.randomization`][elastic_gym.envs.randomization]),
the payload changes, the sensor and actuator delays with the actuator delay line, and
`info["plant"]`. It gives a new setting to the simulator and the sensors through their
own methods (`ArmSimulator.set_link_scaling`, `PlantArray.set`, `Sensors.configure`, ...).

Everything here acts on the simulated plant only; the nominal model never sees it.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence

import numpy as np

from elastic_gym.envs.arm_config import ArmResolver, ArmSettings
from elastic_gym.envs.config import PlantRange
from elastic_gym.envs.disturbances import TorquePulses, given_pulses, random_pulses
from elastic_gym.envs.measurement import Sensors
from elastic_gym.envs.randomization import PATHS, draw, plant_stream, with_values
from elastic_gym.envs.simulator import ArmSimulator


class PlantState:
    """The per-arm plant state of a batch.

    Args:
        settings: each arm's settings at construction.
        ranges: each arm's `randomize` ranges by parameter path.
        arm_kwargs: each arm's per-arm kwargs (what a draw is merged into).
        resolver: turns an arm's kwargs into its settings and plant model.
        torque_limit: the motor torque limits (n,) (torque pulses are fractions of them).
        sim: the simulator whose plants, link scalings and payloads follow the settings.
        sensors: the sensors whose error models follow the settings.

    Attributes (read by the other parts):
        settings: each arm's current settings.
        sensor_delay: each arm's measurement delay in control periods (N,).
        actuator_delay: each arm's actuator delay in control periods (N,).
        payload_mass: each arm's current payload mass (kg) (N,) (0 without a payload).
        drawn: the value each arm drew for each randomized path (N,) (NaN: not drawn).
        pulses: the torque pulses of every arm.
    """

    def __init__(
        self,
        settings: Sequence[ArmSettings],
        ranges: Sequence[Mapping[str, PlantRange]],
        arm_kwargs: Sequence[Mapping],
        resolver: ArmResolver,
        torque_limit: np.ndarray,
        sim: ArmSimulator,
        sensors: Sensors,
    ) -> None:
        self.settings = list(settings)
        self.ranges, self.arm_kwargs = list(ranges), list(arm_kwargs)
        self.resolver, self.torque_limit = resolver, torque_limit
        self.sim, self.sensors = sim, sensors
        N, n = len(self.settings), sim.n
        self.plant_rngs: list[np.random.Generator | None] = [None] * N
        self._plant_sources: list[np.random.Generator | None] = [None] * N
        self.sensor_delay = np.array([s.sensor_delay for s in self.settings])
        self.actuator_delay = np.array([s.actuator_delay for s in self.settings])
        self.pulses = TorquePulses(N, n)
        self._line = 1 + max(self._highest("actuator_delay"))
        self._commands = np.zeros((self._line, N, n))
        self._slot = 0
        self._arms = np.arange(N)
        self.payload_mass = np.zeros(N)
        self._change_time = np.full(N, np.inf)
        self._changes = any(s.payload is not None and s.payload.change for s in self.settings)
        self._stream = [
            bool(r) or (s.pulses is not None and s.pulses.random is not None)
            for s, r in zip(self.settings, self.ranges, strict=True)
        ]
        paths = [p for p in PATHS if any(p in r for r in self.ranges)]
        self.drawn = {path: np.full(N, np.nan) for path in paths}
        self._arm_values: dict[int, dict] = {}  # info's plain values of one arm, by arm
        for arm, arm_settings in enumerate(self.settings):
            self._set_payload(arm, arm_settings, initial=True)
            pulses = arm_settings.pulses
            if pulses is not None and pulses.random is None:
                self.pulses.set(arm, *given_pulses(pulses, torque_limit))

    def _highest(self, path: str) -> list[int]:
        """Every delay an arm of the batch can have on ``path`` (its setting and the
        largest its range can draw)."""
        return [getattr(s, path) for s in self.settings] + [
            int(r[path].maximum) for r in self.ranges if path in r
        ]

    @property
    def sensor_line(self) -> int:
        """Slots of a sensor delay line: 1 + the largest sensor delay an arm can have."""
        return 1 + max(self._highest("sensor_delay"))

    # ------------------------------------------------------------------ resets
    def reset(self, arms: np.ndarray, rngs: Sequence[np.random.Generator]) -> None:
        """New episodes of ``arms``: their draws (plant stream, derived from their arm
        generator of ``rngs`` when it is a new one), initial payloads."""
        self._arm_values.clear()
        for arm in arms:
            if self._stream[arm] and self._plant_sources[arm] is not rngs[arm]:
                self._plant_sources[arm] = rngs[arm]
                self.plant_rngs[arm] = plant_stream(rngs[arm])
            rng = self.plant_rngs[arm]
            if self.ranges[arm]:
                values = draw(self.ranges[arm], rng)
                self.apply(arm, self.resolver.settings(with_values(self.arm_kwargs[arm], values)))
                for path, value in values.items():
                    self.drawn[path][arm] = value
            else:
                self._set_payload(arm, self.settings[arm])
            pulses = self.settings[arm].pulses
            if pulses is not None and pulses.random is not None:
                self.pulses.set(arm, *random_pulses(pulses.random, rng, self.torque_limit))

    def apply(self, arm: int, settings: ArmSettings) -> None:
        """Give arm ``arm`` the plant and sensors of ``settings``."""
        sim = self.sim
        self._arm_values.clear()
        self.settings[arm] = settings
        sim.plants.set(arm, self.resolver.plant_model(settings))
        sim.set_link_scaling(arm, settings.scaling)
        self._set_payload(arm, settings, initial=True)
        self.sensors.configure(arm, settings)
        self.sensor_delay[arm] = settings.sensor_delay
        self.actuator_delay[arm] = settings.actuator_delay

    def _set_payload(self, arm: int, settings: ArmSettings, initial: bool = False) -> None:
        """The configured initial payload of ``arm`` (PyBullet and the plant model; the model
        is rebuilt only when the mass changed or ``initial``)."""
        payload = settings.payload
        if payload is None:
            return
        self._arm_values.clear()
        if initial or self.payload_mass[arm] != payload.mass:
            if not initial:
                self.sim.plants.set(arm, self.resolver.plant_model(settings))
            self.sim.set_payload_mass(arm, payload.mass)
        self.payload_mass[arm] = payload.mass
        self._change_time[arm] = np.inf if payload.change is None else payload.change.time
        self._changes = self._changes or payload.change is not None

    def _set_payload_mass(self, arm: int, mass: float) -> None:
        """Arm ``arm``'s payload of ``mass`` (kg) in its plant model and in PyBullet."""
        self.sim.plants.set(arm, self.resolver.plant_model(self.settings[arm], mass))
        self.sim.set_payload_mass(arm, mass)

    def reset_commands(self, arms: np.ndarray, torque: np.ndarray) -> None:
        """Fill the actuator delay line of ``arms`` with their reset torque (rows)."""
        if self._line > 1:
            self._commands[:, arms] = torque

    # ------------------------------------------------------------------ steps
    @property
    def quiet(self) -> bool:
        """Whether a step has nothing to do here: no actuator delay line, no payload
        change, no torque pulse schedule (`delayed` would return the command and
        `before_step` None)."""
        return self._line == 1 and not self._changes and not self.pulses.start.shape[1]

    def delayed(self, command: np.ndarray) -> np.ndarray:
        """The torques reaching the motors now: each arm's command of actuator_delay
        control periods ago (the newest command enters the line)."""
        if self._line == 1:
            return command
        self._slot = (self._slot + 1) % self._line
        self._commands[self._slot] = command
        return self._commands[(self._slot - self.actuator_delay) % self._line, self._arms]

    def before_step(self, time: np.ndarray) -> np.ndarray | None:
        """Apply the payload changes due at ``time`` (N,), the start of the control period;
        returns the period's link torque pulses (N, n) or None."""
        due = time >= self._change_time if self._changes else None
        if due is not None and due.any():
            self._arm_values.clear()
            for arm in np.flatnonzero(due).tolist():
                mass = self.settings[arm].payload.change.mass
                self._set_payload_mass(arm, mass)
                self.payload_mass[arm] = mass
                self._change_time[arm] = np.inf
        return self.pulses.torque(time)

    # ------------------------------------------------------------------ outputs
    def info(self, arms) -> dict:
        """``info["plant"]`` of ``arms`` (an int: one arm's plain values)."""
        if isinstance(arms, (int, np.integer)):
            k = int(arms)
            out = self.arm_values(k)
            out["torque_pulse"] = self.pulses.current[k].copy()
            self.pulse_schedule(k, out)
            return out
        out = {path: values[arms].copy() for path, values in self.drawn.items()}
        out["actuator_delay"] = self.actuator_delay[arms].copy()
        out["payload.mass"] = self.payload_mass[arms].copy()  # the current mass
        out["torque_pulse"] = self.pulses.current[arms].copy()
        self.pulse_schedule(arms, out)
        return out

    def arm_values(self, k: int) -> dict:
        """A new dict of arm ``k``'s plain values of `info` (its draws, actuator delay and
        payload mass: they change only at a reset or a payload change, so they are kept
        between steps; a dict copy costs less than reading them)."""
        values = self._arm_values.get(k)
        if values is None:
            values = {path: drawn[k].item() for path, drawn in self.drawn.items()}
            values["actuator_delay"] = int(self.actuator_delay[k])
            values["payload.mass"] = float(self.payload_mass[k])  # the current mass
            self._arm_values[k] = values
        return values.copy()

    def pulse_schedule(self, arms, out: dict) -> None:
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

    # ------------------------------------------------------------------ pickling
    _STATE = ("pulses", "_commands", "_slot", "payload_mass", "_change_time", "_changes", "drawn")

    def snapshot(self) -> dict:
        """The arms' settings, the state of their plants (payloads, pulses, the actuator
        delay line, the draws) and of their plant streams: what `restore` takes."""
        return {
            "settings": list(self.settings),
            "state": {key: copy.deepcopy(getattr(self, key)) for key in self._STATE},
            "plant_rngs": [None if r is None else r.bit_generator.state for r in self.plant_rngs],
        }

    def restore(self, snapshot: Mapping, rngs: Sequence[np.random.Generator]) -> None:
        """The plants of a `snapshot`: the drawn settings, payload masses and plant streams
        (each derived from its arm's generator in ``rngs``, as if drawn from it)."""
        for arm, settings in enumerate(snapshot["settings"]):
            if settings != self.settings[arm]:
                self.apply(arm, settings)
        state = snapshot["state"]
        for arm, mass in enumerate(state["payload_mass"]):
            if mass != self.payload_mass[arm]:
                self._set_payload_mass(arm, mass)
        for key, value in state.items():
            setattr(self, key, value)
        self._arm_values.clear()
        for arm, rng_state in enumerate(snapshot["plant_rngs"]):
            if rng_state is not None:
                rng = np.random.default_rng()
                rng.bit_generator.state = rng_state
                self.plant_rngs[arm] = rng
                self._plant_sources[arm] = rngs[arm]
