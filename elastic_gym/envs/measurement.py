"""The sensors of N arms: what a real arm measures of the simulated state.

`Sensors` holds the position encoders and the accelerometers of a batch (each arm its own
error model, [`elastic_gym.envs.sensors`][elastic_gym.envs.sensors]), the observation
space they give and the readings of the arms at the current state: θ (motor encoders of
an elastic arm) or q (link encoders of a rigid one), and the specific force of each
accelerometer, f = R_WSᵀ (a_W − g_W) (eq. (9) of De Luca et al. 2007). Where the readings
go next (the delay line, the observation) is the episode's
([`EpisodeState.record`][elastic_gym.envs.episode.EpisodeState.record]).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from gymnasium import spaces

from elastic_gym.envs.arm_config import ArmSettings
from elastic_gym.envs.sensors import AccelerometerArray, Encoder
from elastic_gym.envs.simulator import ArmSimulator


class Sensors:
    """Encoders and accelerometers of N arms with n joints and ``n_sensors`` accelerometers.

    Args:
        settings: each arm's settings (its encoder and accelerometer error models).
        n_joints: joints per arm.
        n_sensors: 3-axis accelerometers per arm (the nominal model's mounts).
        control_dt: the sampling period of the accelerometers (s).
        elastic: whether the encoders read the motors (elastic joints) or the links.
    """

    def __init__(
        self,
        settings: Sequence[ArmSettings],
        n_joints: int,
        n_sensors: int,
        control_dt: float,
        elastic: bool,
    ) -> None:
        N, n = len(settings), n_joints
        self.n_joints, self.n_sensors, self.elastic = n, n_sensors, elastic
        self.encoder = Encoder(
            [s.encoder[0] for s in settings], [s.encoder[1] for s in settings], n, N
        )
        self.accelerometer_array = AccelerometerArray(
            [s.accelerometer for s in settings], n_sensors, control_dt, N
        )
        self.position_key = "motor_position" if elastic else "link_position"

    def observation_space(self) -> spaces.Dict:
        """One arm's observation: the encoders, the accelerometers (when the arm has any,
        bounded by the largest range) and the reference q_d, q_d'."""
        n = self.n_joints
        inf = np.full(n, np.inf)
        entries: dict[str, spaces.Space] = {
            self.position_key: spaces.Box(-inf, inf, dtype=np.float64)
        }
        if self.n_sensors:
            r = np.full(3 * self.n_sensors, self.accelerometer_array.config.range)
            entries["acceleration"] = spaces.Box(-r, r, dtype=np.float64)
        entries["reference"] = spaces.Box(
            -np.full(2 * n, np.inf), np.full(2 * n, np.inf), dtype=np.float64
        )
        return spaces.Dict(entries)

    def configure(self, arm: int, settings: ArmSettings) -> None:
        """Arm ``arm``'s error models from its ``settings`` (e.g. drawn at a reset)."""
        self.encoder.set(arm, *settings.encoder)
        self.accelerometer_array.set(arm, settings.accelerometer)

    def reset(self, arms: np.ndarray, rngs: list[np.random.Generator]) -> None:
        """New episodes of ``arms``: accelerometer biases drawn from their generators
        (``rngs``: every arm's), filters and noise blocks restarted."""
        self.accelerometer_array.reset(arms, rngs)
        self.encoder.restart(arms)

    def read(
        self,
        sim: ArmSimulator,
        ddq: np.ndarray,
        arms: np.ndarray,
        every: bool,
        rngs: list[np.random.Generator],
        forces: np.ndarray | None = None,
    ) -> dict[str, np.ndarray]:
        """The readings of ``arms`` (``every``: ``arms`` is every arm in order, the whole
        arrays are read) by observation key, their noise drawn from their generators
        (``rngs``: every arm's). ``forces``: the noise-free accelerometer readings of every
        arm (N, 3 n_sensors), if already known; else they are computed at q'' = ``ddq``."""
        rows = slice(None) if every else arms
        arm_rngs = rngs if every else [rngs[i] for i in arms]
        position = sim.theta if self.elastic else sim.q
        readings = {self.position_key: self.encoder.measure(position[rows], arm_rngs, arms)}
        if self.n_sensors:
            if forces is not None:
                force = forces if every else forces[arms]
            else:
                chain = sim.plants.chain
                chain = chain if every else chain.select(arms)
                force = chain.specific_forces(sim.q[rows], sim.dq[rows], ddq[rows])
            readings["acceleration"] = self.accelerometer_array.measure(force, arm_rngs, arms)
        return readings

    # ------------------------------------------------------------------ pickling
    def snapshot(self) -> dict:
        """The sensors' own state (noise blocks, biases, filters); their error models are
        the arms' settings."""
        return {
            "encoder": self.encoder.noise.snapshot(),
            "accelerometers": self.accelerometer_array.snapshot(),
        }

    def restore(self, snapshot: dict) -> None:
        """The state of a `snapshot`, in place."""
        self.encoder.noise.restore(snapshot["encoder"])
        self.accelerometer_array.restore(snapshot["accelerometers"])
