"""The packed arguments of a batch's fused kernels, built when needed and kept while valid.

numba unboxes every array of a call's arguments at every dispatch (a `Packed` of
`elastic_gym.model.packed` holds them as one); the two kernels of a control period
([`elastic_gym.envs.kernels`][elastic_gym.envs.kernels]) take some 80 arrays and scalars,
so `FusedArguments` packs them once: the simulator's state and plant constants, the
sensors' error models and noise blocks, the episode's arrays (all changed in place by the
kernels and by resets), the limits and the reward constants. A pack shares the arrays, it
does not copy them; it is built again after a reset (an arm's sensors or plant may have
changed) and, for the control period's pack, when the simulator packed its own arguments
again (new plants) or the episode length changed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from elastic_gym.envs.episode import EpisodeState
from elastic_gym.envs.kernels import control_period_kernel, post_step_kernel
from elastic_gym.envs.measurement import Sensors
from elastic_gym.envs.sensors import GaussianNoise
from elastic_gym.envs.simulator import ArmSimulator
from elastic_gym.envs.task_base import Task
from elastic_gym.model.packed import Packed, direct


@dataclass(frozen=True)
class Fused:
    """The arguments of one episode's fused kernels.

    Attributes:
        end: `post_step_kernel`'s `packed`.
        coupling: its `coupling` (model (2)'s arguments; matrices (N, 0, 0) for model (1)
            and rigid arms).
        forces: the accelerometers' noise-free readings it writes (N, 3 n_sensors) (the
            step by step measurement reads them when an arm broke).
        period: `control_period_kernel`'s arguments after the torques and the truncation
            flags (`bullet`, `rk4`, `packed`), or None where the simulator cannot step
            through PyBullet's C API or the task has no compiled form.
        noises: the noise streams the end of a period draws from (those of a standard
            deviation > 0: a stream of std 0 draws nothing).
        end_call: `post_step_kernel`'s entry point for these arguments (`direct`:
            without numba's dispatch; the batch's own arrays, an int slot, a fresh
            float64 reward array).
        period_call: `control_period_kernel`'s for `period` and motor torques of
            C-contiguous, writeable float64 (N, n) (the kernel itself without `period`).
    """

    end: Packed
    coupling: Packed
    forces: np.ndarray
    period: tuple[Packed | None, Packed | None, Packed] | None
    noises: tuple[GaussianNoise, ...]
    end_call: Callable[..., bool]
    period_call: Callable[..., tuple[int, bool]]

    def refill(self, rngs: list[np.random.Generator]) -> None:
        """Fresh noise blocks for the arms whose block is used up (from their generators,
        in sensor order), before the end of a period draws from them."""
        for noise in self.noises:
            if noise.room:  # `GaussianNoise.refill`'s count down, without the call
                noise.room -= 1
            else:
                noise.refill(rngs)


class FusedArguments:
    """The fused kernels' arguments of a batch's parts.

    Args:
        sim: the simulator (state, plants, its own packed substep arguments).
        task: the task (its compiled arguments, if any).
        sensors: the encoders and accelerometers.
        episode: the episode arrays.
        torque_limit: the motor torque limits (n,).
        joint_limits: the joints' (lower, upper) limits (n,) each.
        max_velocity: |q'| or |theta'| above this ends an episode (rad/s).
        reward_constants: the reward kernel's arguments after the torque limit and the
            torsion (`RewardConfig.kernel_constants`).
        n_substeps: physics steps per control period.
    """

    def __init__(
        self,
        sim: ArmSimulator,
        task: Task,
        sensors: Sensors,
        episode: EpisodeState,
        torque_limit: np.ndarray,
        joint_limits: tuple[np.ndarray, np.ndarray],
        max_velocity: float,
        reward_constants: tuple,
        n_substeps: int,
    ) -> None:
        self.sim, self.task, self.sensors, self.episode = sim, task, sensors, episode
        self.torque_limit, self._minus_limit = torque_limit, -torque_limit
        self._limit_row = torque_limit[None]
        self.joint_limits, self.max_velocity = joint_limits, max_velocity
        self.reward_constants, self.n_substeps = reward_constants, n_substeps
        self._no_readings = np.zeros((episode.n_arms, 0))  # the accelerometers of none
        self._built: Fused | bool | None = False  # False: not built since the last reset
        self._period: tuple | None = None  # (the simulator's pack it holds, the pack)

    def invalidate(self) -> None:
        """Build the arguments again when next needed (after a reset: an arm's sensors or
        plant may have changed)."""
        self._built = False

    def forget_period(self) -> None:
        """Pack the control period's arguments again (a new episode length)."""
        self._built, self._period = False, None

    def get(self) -> Fused | None:
        """The episode's arguments (built if needed), or None when the batch needs the step
        by step path: an arm with its own sensor error model, an accelerometer filter."""
        built = self._built
        if built is False:
            built = self._built = self._build()
        return built  # type: ignore[return-value]

    def _build(self) -> Fused | None:
        sim, sensors, episode = self.sim, self.sensors, self.episode
        encoder, acc = sensors.encoder, sensors.accelerometer_array
        plants, n_sensors = sim.plants, sensors.n_sensors
        resolution, noise_std = encoder.shared
        sample_std, alpha, limit, acc_resolution = acc.shared
        if (
            resolution is None
            or noise_std is None
            or (
                n_sensors
                and (alpha != 0.0 or sample_std is None or limit is None or acc_resolution is None)
            )
        ):
            return None
        N, n = episode.ddq.shape
        shape = (N, n)
        forces = np.empty((N, 3 * n_sensors))
        transmission = (  # the transmission kernel's arguments after tau
            *plants.transmission,
            sensors.elastic,
            np.empty(shape),
            np.empty(shape),
            np.empty(shape),
            0.0,
        )
        dynamics = plants.chain.dynamics_and_forces_arguments(episode.ddq, forces)
        limits = (*self.joint_limits, self.max_velocity, episode.codes)
        size = 3 * n_sensors
        no_readings = self._no_readings
        obs, lines = episode.obs, episode.lines
        position = sensors.position_key
        sensor_arguments = (
            sensors.elastic,
            noise_std,
            encoder.noise.block,
            encoder.noise.next,
            resolution,
            bool(n_sensors),
            acc.bias,
            sample_std if n_sensors else 0.0,
            acc.noise.block,
            acc.noise.next,
            limit if n_sensors else np.inf,
            acc_resolution if n_sensors else 0.0,
            np.empty(shape),
            np.empty((N, size)),
            lines[position],
            lines["acceleration"] if n_sensors else no_readings[None],
            episode.sensor_delay,
            obs[position],
            obs["acceleration"] if n_sensors else no_readings,
            obs["reference"],
        )
        rewards = (self._limit_row, *self.reward_constants)
        drawn = [(encoder.noise, noise_std)] + ([(acc.noise, sample_std)] if n_sensors else [])
        noises = [noise for noise, std in drawn if std is not None and std > 0.0]
        state = (sim.theta, sim.dtheta, sim.q, sim.dq)
        coupling = sim.coupling_arguments()
        # the RK4's q'' at the end of a period (PyBullet: none, an array of the same type)
        integrated = (episode.ddq, False) if sim.rk4 is None else (sim.rk4.ddq, True)
        scratch = np.empty((3, N, n))
        ends = (
            dynamics,
            limits,
            sensor_arguments,
            rewards,
            integrated,
            scratch,
            sim.no_link_torque,
        )
        end = Packed((*state, transmission, *ends))
        period = self.period()
        torque = (episode.clipped, episode.previous_torque, episode.reference)
        end_call = direct(post_step_kernel, *torque, episode.slot, np.empty(N), coupling, end)
        period_call: Callable[..., tuple[int, bool]] = control_period_kernel
        if period is not None:
            truncation = episode.truncation()
            period_call = direct(control_period_kernel, episode.clipped, truncation, *period)
        return Fused(end, coupling, forces, period, tuple(noises), end_call, period_call)

    def period(self) -> tuple[Packed | None, Packed | None, Packed] | None:
        """`control_period_kernel`'s arguments after the torques and the truncation flags,
        or None where the simulator cannot step through PyBullet's C API or the task has
        no compiled form: the simulator's
        [`period_arguments`][elastic_gym.envs.simulator.ArmSimulator.period_arguments]
        (PyBullet's or the RK4's, each packed, the other None) and the `packed` rest: the
        torque limits (low, high), the clipped torque, the saturation flags and the
        open-loop torque (outputs), the task's open-loop torque arguments, q, the
        substeps per period, the clock (steps, control period, episode length in periods
        or -1, time), the torques (current, previous), the reference and the task's
        reference arguments
        ([`Task.compiled_arguments`][elastic_gym.envs.task_base.Task.compiled_arguments]).

        Packing costs about 0.35 ms (numba types the nested tuple in Python), so the packs
        are kept across resets, which change their arrays in place, and made again only
        when the simulator packed its own arguments again (new plants) or `forget_period`
        was called (a new episode length)."""
        sim, episode = self.sim, self.episode
        physics, task = sim.period_arguments(), self.task.compiled_arguments()
        if physics is None or task is None:
            return None
        bullet, rk4 = physics  # the simulator's packs identify its arguments
        key = bullet[2:4] if bullet is not None else rk4[-1:]
        if self._period is not None and self._period[0] == key:
            return self._period[1]
        task_torque, task_reference = task
        packed = Packed(
            (
                self._minus_limit,
                self.torque_limit,
                episode.clipped,
                episode.saturated,
                episode.external,
                task_torque,
                sim.q,
                self.n_substeps,
                episode.steps,
                episode.control_dt,
                episode.length,
                episode.time,
                episode.torque,
                episode.previous_torque,
                episode.reference,
                task_reference,
            )
        )
        period = (
            None if bullet is None else Packed(bullet),
            None if rk4 is None else Packed(rk4),
            packed,
        )
        self._period = (key, period)
        return period
