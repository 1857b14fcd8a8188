"""N arms of one robot in one PyBullet world: the simulation core of every env.

:class:`ArmBatch` holds everything an episode needs, for N arms at once, in arrays with a
leading arm axis: the simulator, the sensors, the task and its reference, the reward, the
termination checks and the info. :class:`~elastic_gym.envs.arm_env.ArmEnv` is its N = 1
case and :class:`~elastic_gym.envs.vector_env.ArmVectorEnv` exposes all N arms as a
Gymnasium vector env; there is no second copy of the physics.

Exactness: arm i draws every random number from its own generator (its plant from its own
plant stream, :mod:`~elastic_gym.envs.randomization`), and every computation on it depends
only on its own rows, with the same operations in the same order whatever N. So arm i of a
batch seeded s + i is bit for bit the single env reset with seed s + i under the same
actions, and with ``per_arm`` the single env made with arm i's merged kwargs. The
observation holds only what a real arm measures; the truth, the applied torque, the
reference and the plant's own parameters are in ``info`` (see :class:`ArmBatch`).
"""

from __future__ import annotations

import contextlib
import functools
import inspect
from collections.abc import Iterator
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from numba import njit

from elastic_gym.arms import REFERENCE_KEYS
from elastic_gym.envs import bullet_capi
from elastic_gym.envs.arm_config import ArmResolver, ArmSettings, arm_kwargs
from elastic_gym.envs.config import (
    EPISODE_TIME,
    PER_ARM_KEYS,
    ElasticResetOptions,
    EnvConfig,
    PlantRange,
    RigidResetOptions,
)
from elastic_gym.envs.memory import check_batch_memory
from elastic_gym.envs.plant import PlantArray
from elastic_gym.envs.plant_state import PlantState
from elastic_gym.envs.randomization import check_ranges, with_values
from elastic_gym.envs.reward import RewardConfig, _reward_kernel, batch_reward
from elastic_gym.envs.sensors import (
    AccelerometerArray,
    AccelerometerConfig,
    Encoder,
    EncoderConfig,
    _shared_readings,
    every_arm,
)
from elastic_gym.envs.simulator import ArmSimulator, _end_of_period_dynamics, _period_kernel
from elastic_gym.envs.tasks import make_task, open_loop_torque_kernel, reference_kernel
from elastic_gym.model import ParameterScaling, RobotModel
from elastic_gym.model.packed import Packed
from elastic_gym.robots.catalog import get_robot
from elastic_gym.robots.spec import AccelerometerMount, RobotSpec, substeps
from elastic_gym.robots.urdf_tools import joint_limits
from elastic_gym.validation import checked_count, errors_at, numbers, per_joint_values, validated

STABILITY_LIMIT = 0.2  # largest admissible physics_dt * omega_max


REASONS = np.array(
    [None, "joint limit exceeded", "velocity limit exceeded", "non-finite state"], dtype=object
)


@njit(cache=True)
def _break_codes(q, dq, theta, dtheta, lower, upper, max_velocity, codes):
    """Per arm: 0 (the physics holds), 1 (a joint limit crossed), 2 (|q'| or |theta'| above
    max_velocity), 3 (a non-finite state), the most severe one; returns whether any arm
    broke."""
    broken = False
    for k in range(q.shape[0]):
        code = 0
        for j in range(q.shape[1]):
            values = (q[k, j], dq[k, j], theta[k, j], dtheta[k, j])
            if not (
                np.isfinite(values[0])
                and np.isfinite(values[1])
                and np.isfinite(values[2])
                and np.isfinite(values[3])
            ):
                code = 3
            elif abs(values[1]) > max_velocity or abs(values[3]) > max_velocity:
                code = max(code, 2)
            elif values[0] < lower[j] or values[0] > upper[j]:
                code = max(code, 1)
        codes[k] = code
        broken = broken or code > 0
    return broken


@njit(cache=True)
def _clip_torque(command, external, low, high, tau, saturated):
    """tau = min(max(command + external, low), high) per joint (``external`` None: none),
    as numpy's addition, maximum and minimum give it (NaN stays NaN), and per arm whether
    any joint's torque changed in the clip (NaN: changed)."""
    for k in range(command.shape[0]):
        changed = False
        for j in range(command.shape[1]):
            c = command[k, j]
            if external is not None:
                c = c + external[k, j]
            v = low[j] if c < low[j] else c
            v = high[j] if v > high[j] else v
            tau[k, j] = v
            changed = changed or v != c
        saturated[k] = changed


@njit(cache=True)
def _advance_clock(steps, stepping, dt, max_steps, time, truncated):
    """steps += 1 for the stepping arms (``stepping`` None: every arm), time = steps dt
    (numpy's int64 by float64 product) and truncated = steps >= max_steps (not written
    when ``max_steps`` is None); returns whether any arm is truncated."""
    ended = False
    for k in range(steps.shape[0]):
        if stepping is None or stepping[k]:
            steps[k] += 1
        time[k] = steps[k] * dt
        if max_steps is not None:
            truncated[k] = steps[k] >= max_steps
            ended = ended or truncated[k]
    return ended


@njit(cache=True)
def _post_step_kernel(tau, previous, reference, slot, reward, packed):
    """The end of a control period of every arm in one call, the same kernels in the same
    order as :meth:`ArmBatch.step` calls them one by one (so bit for bit the same):

    1. q'' and the noise-free accelerometer readings (eq. (9)): the simulator's
       :func:`~elastic_gym.envs.simulator._end_of_period_dynamics` (``transmission``,
       ``dynamics``: the arguments after the motor torques ``tau`` of its
       ``_link_dynamics_kernel``; no link-side torque; ``coupling``: model (2)'s);
    2. the termination codes (:func:`_break_codes`, ``limits``: its arguments after the
       state); if an arm broke, returns False here (the caller measures with the hold of
       non-finite readings);
    3. the encoders' and accelerometers' readings (:func:`~elastic_gym.envs.sensors.
       _shared_readings`: one error model for every arm, no filter), through the sensor
       delay line (``slot``: its newest slot), into the observation with the reference
       q_d, q_d' (``reference`` (N, 5, n));
    4. the reward (:func:`~elastic_gym.envs.reward._reward_kernel`, into ``reward`` (N,))
       at e = q - q_d, e' = q' - q_d', torsion theta - q, the torques ``tau`` and
       ``previous``.

    ``packed``: a :class:`~elastic_gym.model.packed.Packed` of what holds for the episode,
    (theta, theta', q, q', transmission, coupling (None without model (2)), dynamics,
    limits, sensors, the torque limit row and the reward constants after it); ``sensors``:
    (elastic, encoder std, block, next, resolution, has accelerometers, bias, std, block,
    next, range, resolution, readings (encoders, accelerometers), delay lines (L, N, size)
    of both, delays (N,), observation arrays (position, acceleration, reference))."""
    theta, dtheta, q, dq, transmission, coupling = packed.values[:6]
    dynamics, limits, sensors, rewards = packed.values[6:]
    (
        elastic,
        enc_std,
        enc_block,
        enc_next,
        enc_resolution,
        has_acc,
        acc_bias,
        acc_std,
        acc_block,
        acc_next,
        acc_range,
        acc_resolution,
        position_reading,
        acc_reading,
        position_line,
        acc_line,
        delay,
        position_obs,
        acc_obs,
        reference_obs,
    ) = sensors
    forces = dynamics[3]
    _end_of_period_dynamics(theta, dtheta, q, dq, tau, transmission, coupling, dynamics)
    if _break_codes(q, dq, theta, dtheta, *limits):
        return False
    _shared_readings(
        theta if elastic else q,
        None,
        enc_std,
        enc_block,
        enc_next,
        np.inf,
        enc_resolution,
        position_reading,
    )
    if has_acc:
        _shared_readings(
            forces, acc_bias, acc_std, acc_block, acc_next, acc_range, acc_resolution, acc_reading
        )
    N, n = q.shape
    length = position_line.shape[0]
    for k in range(N):
        if length > 1:
            oldest = (slot - delay[k]) % length
            for j in range(position_reading.shape[1]):
                position_line[slot, k, j] = position_reading[k, j]
                position_obs[k, j] = position_line[oldest, k, j]
            if has_acc:
                for j in range(acc_reading.shape[1]):
                    acc_line[slot, k, j] = acc_reading[k, j]
                    acc_obs[k, j] = acc_line[oldest, k, j]
        else:
            for j in range(position_reading.shape[1]):
                position_obs[k, j] = position_reading[k, j]
            if has_acc:
                for j in range(acc_reading.shape[1]):
                    acc_obs[k, j] = acc_reading[k, j]
        for j in range(n):
            reference_obs[k, j] = reference[k, 0, j]
            reference_obs[k, n + j] = reference[k, 1, j]
    error, error_rate, torsion = np.empty((N, n)), np.empty((N, n)), np.empty((N, n))
    for k in range(N):
        for j in range(n):
            error[k, j] = q[k, j] - reference[k, 0, j]
            error_rate[k, j] = dq[k, j] - reference[k, 1, j]
            torsion[k, j] = theta[k, j] - q[k, j]
    _reward_kernel(error, error_rate, tau, previous, rewards[0], torsion, *rewards[1:], reward)
    return True


@njit(cache=True)
def _control_period_kernel(command, truncated, packed):
    """A control period of every arm up to its end (:func:`_post_step_kernel`) in one call,
    the kernels of :meth:`ArmBatch._period_step_by_step` in its order (so bit for bit the
    same):

    1. the task's open-loop torque at the period's start
       (:func:`~elastic_gym.envs.tasks.open_loop_torque_kernel`) added to ``command`` and
       clipped to the torque limits (:func:`_clip_torque`);
    2. the physics substeps (:func:`~elastic_gym.envs.simulator._period_kernel`);
    3. the clock (:func:`_advance_clock`, ``truncated`` written when episodes have a
       length) and the torques shifted (previous <- current <- the clipped torque);
    4. the reference at the new time (:func:`~elastic_gym.envs.tasks.reference_kernel`).

    ``packed``: a :class:`~elastic_gym.model.packed.Packed` of the batch's arrays changed
    in place (see :meth:`ArmBatch._period_arguments`). Returns (the physics' bullet_capi
    code, whether an arm is truncated); after a code other than OK nothing past step 2
    has run. (The end of the period is a call of its own: compiled into this kernel it
    would cost each of its variants as much compile time again, for 3 us per step.)"""
    (low, high, tau, saturated, external, task_torque, q, physics, n_substeps) = packed.values[:9]
    (steps, dt, max_steps, time, torque, previous, reference, task_reference) = packed.values[9:]
    if open_loop_torque_kernel(time, q, external, task_torque):
        _clip_torque(command, external, low, high, tau, saturated)
    else:
        _clip_torque(command, None, low, high, tau, saturated)
    world_slot, world, state, coupling, states = physics
    code = _period_kernel(world_slot, world, n_substeps, tau, None, state, coupling, states)
    if code != bullet_capi.OK:
        return code, False
    ended = _advance_clock(steps, None, dt, max_steps, time, truncated)
    for k in range(tau.shape[0]):
        for j in range(tau.shape[1]):
            previous[k, j] = torque[k, j]
            torque[k, j] = tau[k, j]
    reference_kernel(time, task_reference, reference)
    return code, ended


@njit(cache=True)
def _arm_values(k, theta, q, dtheta, dq, ddq, reference, torque, readings, limit, out):
    """One fresh copy of arm k's info arrays, flat: theta, q, theta', q', q'', the
    reference's rows (q_d .. q_d^(4)) and tau, n numbers each; returns whether one of its
    accelerometer ``readings`` (N, 3 n_sensors) is at the range ``limit`` (N,)
    (:func:`_at_range`)."""
    n = q.shape[1]
    for j in range(n):
        out[j] = theta[k, j]
        out[n + j] = q[k, j]
        out[2 * n + j] = dtheta[k, j]
        out[3 * n + j] = dq[k, j]
        out[4 * n + j] = ddq[k, j]
        for r in range(reference.shape[1]):
            out[(5 + r) * n + j] = reference[k, r, j]
        out[(5 + reference.shape[1]) * n + j] = torque[k, j]
    return _at_range(readings[k], limit[k])


@njit(cache=True)
def _at_range(readings, limit):
    """Whether any |reading| >= limit (a NaN reading is not), as numpy's
    ``np.fmax.reduce(np.abs(readings)) >= limit`` gives it."""
    for j in range(readings.shape[0]):  # noqa: SIM110 - a loop numba compiles
        if abs(readings[j]) >= limit:
            return True
    return False


def with_batch_options(init):
    """Give an env ``__init__(self, ..., **kwargs)`` that forwards ``kwargs`` to
    :class:`ArmBatch` the signature it really accepts (``inspect.signature``, ``help``,
    keyword validation by the comparison runner), and refuse unknown keywords."""
    own = inspect.signature(init)
    batch = [
        p
        for name, p in inspect.signature(ArmBatch.__init__).parameters.items()
        if name in ArmBatch.KWARGS
    ]
    fixed = [p for p in own.parameters.values() if p.kind is not p.VAR_KEYWORD]
    signature = own.replace(parameters=[*fixed, *(p.replace(kind=p.KEYWORD_ONLY) for p in batch)])

    @functools.wraps(init)
    def checked(self, *args, **kwargs):
        unknown = set(kwargs) - set(own.parameters) - set(ArmBatch.KWARGS)
        if unknown:
            raise TypeError(
                f"{type(self).__name__}() got an unexpected keyword argument "
                f"{sorted(unknown)[0]!r}; valid: {sorted(ArmBatch.KWARGS)}"
            )
        init(self, *args, **kwargs)

    checked.__signature__ = signature
    return checked


class ArmBatch:
    """N arms of a robot of the catalog: simulation, sensors, task, reward, termination.

    Args:
        robot: robot name (``elastic_gym.robots.catalog.ROBOTS``) or a ``RobotSpec``.
        n_arms: number of arms (N).
        task: ``"tracking"``, ``"regulation"`` or ``"excitation"``.
        task_options: options of the task (see ``elastic_gym.envs.tasks``).
        physics_dt: physics step (s), default from the robot; must keep
            ``physics_dt * omega_max <= 0.2`` for the stiffest joint mode.
        control_dt: control period (s), an integer multiple of ``physics_dt`` (default 1 ms).
        encoder: ``{"resolution": rad, "noise_std": rad}``.
        accelerometer: error model, see ``AccelerometerConfig`` (``"ideal"`` for none).
        accelerometers: list of mounts ``{"link", "position", "rpy", "name"}`` replacing
            the robot's default sensor placement.
        plant_scaling: parameter changes of the *simulated* robot relative to the nominal
            model (``ParameterScaling`` fields, e.g. ``{"link_mass": 1.3}``).
        unmodelled_friction: link-side joint friction of the *simulated* robot that no
            model knows, ``{"coulomb": c, "viscous": v}`` (scalars or per joint) in
            fractions of each joint's motor torque limit:
            d(q') = tau_max (v q' + c tanh(q' / 0.01 rad/s)), added to the robot's own.
        torque_limit: override of the motor torque limits (N m).
        reward: weights and scales of the reward, see
            :class:`~elastic_gym.envs.reward.RewardConfig` (also the termination reward).
        max_velocity: |q'| or |theta'| above this ends the episode (rad/s).
        sensor_delay: measurement delay in control periods (encoders and accelerometers;
            the reference is not delayed).
        actuator_delay: the motor torque is applied this many control periods late.
        payload: a point mass at the end effector, ``{"mass", "position", "change":
            {"time", "mass"}}`` (see :mod:`elastic_gym.envs.config`).
        torque_pulses: link-side torque pulses, given or random (see
            :mod:`elastic_gym.envs.config` and :mod:`elastic_gym.envs.disturbances`).
        randomize: parameter path -> range drawn by each arm at every reset (see
            :mod:`elastic_gym.envs.randomization`).
        per_arm: None or N mappings of the per-arm kwargs (``plant_scaling``,
            ``unmodelled_friction``, ``encoder``, ``accelerometer``, ``sensor_delay``,
            ``actuator_delay``, ``payload``, ``torque_pulses``, ``randomize``): arm i's
            kwargs are the shared ones deep-merged with mapping i, and arm i is bit for bit
            the single env made with them.
        episode_time: simulated seconds after which an episode is truncated (None: never).
        gui: show the PyBullet GUI (render_mode="human").

    ``info["plant"]`` is a flat mapping path -> value of the simulated plant's own
    parameters: ``actuator_delay``, ``payload.mass`` (0 without a payload, the current
    mass after a change), ``torque_pulse`` (the link torque of the last control period),
    the pulse schedule ``torque_pulses.times`` / ``.durations`` / ``.amplitudes`` when an
    arm has pulses (padded with NaN to the batch's largest pulse count) and every
    randomized path's drawn value (NaN for an arm that does not randomize it).
    """

    KWARGS: ClassVar[tuple[str, ...]] = (
        "task",
        "task_options",
        "physics_dt",
        "control_dt",
        "encoder",
        "accelerometer",
        "accelerometers",
        "plant_scaling",
        "unmodelled_friction",
        "torque_limit",
        "reward",
        "max_velocity",
        "sensor_delay",
        "actuator_delay",
        "payload",
        "torque_pulses",
        "randomize",
        "per_arm",
        "episode_time",
    )

    def __init__(
        self,
        robot: str | RobotSpec,
        n_arms: int = 1,
        task: str = "tracking",
        task_options: dict | None = None,
        physics_dt: float | None = None,
        control_dt: float | None = None,
        encoder: dict | EncoderConfig | None = None,
        accelerometer: dict | AccelerometerConfig | str | None = None,
        accelerometers: list | None = None,
        plant_scaling: dict | ParameterScaling | None = None,
        unmodelled_friction: dict | None = None,
        torque_limit: list | float | None = None,
        reward: dict | RewardConfig | None = None,
        max_velocity: float = 100.0,
        sensor_delay: int = 0,
        actuator_delay: int = 0,
        payload: dict | None = None,
        torque_pulses: dict | None = None,
        randomize: dict | None = None,
        per_arm: list | None = None,
        episode_time: float | None = EPISODE_TIME,
        gui: bool = False,
    ) -> None:
        kwargs = {k: v for k, v in locals().items() if k not in ("self", "__class__")}
        self.init_kwargs = kwargs
        n_arms = checked_count(n_arms, "the number of arms", 1)
        config = validated(EnvConfig, {k: kwargs[k] for k in self.KWARGS})
        spec = robot if isinstance(robot, RobotSpec) else get_robot(robot)
        check_batch_memory(spec.urdf, int(n_arms), spec.name)  # PyBullet would segfault
        self.robot, self.n_arms, self.n_joints = spec, int(n_arms), spec.n_joints
        self.physics_dt, self.control_dt, self.n_substeps = self._timing(config)
        mounts = (
            spec.accelerometers
            if accelerometers is None
            else tuple(AccelerometerMount.from_config(m) for m in accelerometers)
        )
        self.torque_limit = self._torque_limit(torque_limit)
        self.model = RobotModel(spec, accelerometers=mounts)
        models = self._configure_arms(mounts, {k: kwargs[k] for k in PER_ARM_KEYS}, per_arm)
        self.max_velocity, self.episode_time = config.max_velocity, config.episode_time
        self.max_steps = (
            None
            if self.episode_time is None
            else max(1, round(self.episode_time / self.control_dt))
        )
        self.joint_lower, self.joint_upper = joint_limits(spec.urdf, spec.joint_names)
        self.reward_config = RewardConfig.from_config(reward)
        self.task = make_task(task, spec, self.model, task_options, n_arms=self.n_arms)
        for name, points in self.task.configured_points().items():
            self._check_within_limits(f"task_options.{name}", points)
        self._make_sensors()
        self.sim = ArmSimulator(
            spec,
            PlantArray(models),
            self.physics_dt,
            self.n_arms,
            gui=gui,
            payload_positions=[self.resolver.payload_position(s) for s in self.settings],
        )
        self._make_state()

    # ------------------------------------------------------------------ setup
    def _configure_arms(self, mounts, shared: dict, per_arm) -> list[RobotModel]:
        """Each arm's settings (``per_arm`` merged in), randomization ranges and plant
        model; every plant a range can reach is checked for stability."""
        N = self.n_arms
        self.resolver = resolver = ArmResolver(
            self.robot, mounts, self.torque_limit, self.control_dt
        )
        shared_settings = resolver.settings(shared)
        merged = arm_kwargs(shared, per_arm, N)
        self.arm_kwargs = [shared] * N if merged is None else merged
        self.settings, self.ranges, models = [], [], []
        checked: set[tuple] = set()  # plants whose stability is checked
        for i, arm in enumerate(self.arm_kwargs):
            where = "" if merged is None else f"per_arm[{i}]."
            with errors_at(f"per_arm[{i}]"):
                settings = shared_settings if merged is None else resolver.settings(arm)
            ranges = {
                path: validated(PlantRange, spec, f"{where}randomize[{path!r}]")
                for path, spec in (arm.get("randomize") or {}).items()
            }
            corners = check_ranges(ranges, arm, resolver, where)
            if "payload.mass" in ranges and settings.payload is None:  # a payload link is needed
                low = {"payload.mass": ranges["payload.mass"].low}
                settings = resolver.settings(with_values(arm, low))
            self.settings.append(settings)
            self.ranges.append(ranges)
            models.append(resolver.plant_model(settings))
            for option in (settings, *corners):
                masses = [None] if option.payload is None else [None, *self._later_masses(option)]
                for mass in masses:
                    key = (option.scaling, repr(option.payload), mass)
                    if key not in checked:
                        checked.add(key)
                        self._check_stability(resolver.plant_model(option, mass))
        return models

    @staticmethod
    def _later_masses(settings: ArmSettings) -> list[float]:
        change = None if settings.payload is None else settings.payload.change
        return [] if change is None else [change.mass]

    def _check_within_limits(self, name: str, points: np.ndarray) -> None:
        """Refuse configurations ``points`` (the option ``name``) outside the joint limits."""
        if np.any(points < self.joint_lower) or np.any(points > self.joint_upper):
            raise ValueError(
                f"{name}: {points.tolist()} is outside the joint limits "
                f"[{self.joint_lower}, {self.joint_upper}]"
            )

    def _make_sensors(self) -> None:
        N, n = self.n_arms, self.n_joints
        settings = self.settings
        self.encoder = Encoder(
            [s.encoder[0] for s in settings], [s.encoder[1] for s in settings], n, N
        )
        self.accelerometer_array = AccelerometerArray(
            [s.accelerometer for s in settings], self.model.n_sensors, self.control_dt, N
        )
        self.single_observation_space = self._observation_space()
        self.single_action_space = spaces.Box(
            -self.torque_limit, self.torque_limit, dtype=np.float64
        )

    def _make_state(self) -> None:
        N, n = self.n_arms, self.n_joints
        self.rngs = [np.random.default_rng() for _ in range(N)]
        self.plant_rngs: list[np.random.Generator | None] = [None] * N
        self._plant_sources: list[np.random.Generator | None] = [None] * N
        self.steps = np.zeros(N, dtype=np.int64)
        self.running = np.zeros(N, dtype=bool)  # an episode is under way (reset, not ended)
        self.torque = np.zeros((N, n))
        self.previous_torque = np.zeros((N, n))
        self._tau = np.zeros((N, n))  # the clipped torque of a period being computed
        self._external = np.zeros((N, n))  # the task's open-loop torque of that period
        self.saturated = np.zeros(N, dtype=bool)
        self.ddq = np.zeros((N, n))
        self.reference = np.zeros((N, len(REFERENCE_KEYS), n))
        self.reasons = np.full(N, None, dtype=object)
        self._no_reasons = np.full(N, None, dtype=object)  # never written to
        self._no_arm = np.zeros(N, dtype=bool)
        self._no_readings = np.zeros((N, 0))  # the accelerometers of an arm without any
        self._codes = np.zeros(N, dtype=np.int64)
        self._all = np.ones(N, dtype=bool)
        self._arms = every_arm(N)  # (the sensors' whole-array path)
        self._minus_limit = -self.torque_limit
        self._time: np.ndarray = np.zeros(N)
        self.obs = {
            key: np.zeros((N, *(space.shape or ())))
            for key, space in self.single_observation_space.items()
        }
        self.sensor_delay = np.array([s.sensor_delay for s in self.settings])
        self.actuator_delay = np.array([s.actuator_delay for s in self.settings])
        highs = [s.sensor_delay for s in self.settings] + [
            int(r["sensor_delay"].maximum) for r in self.ranges if "sensor_delay" in r
        ]
        self._sensor_line = 1 + max(highs)
        self._measured = {
            key: np.zeros((self._sensor_line, *value.shape))
            for key, value in self.obs.items()
            if key != "reference"
        }
        self._slot = 0  # slot of the newest reading in the delay line
        self.plant_state = PlantState(self)
        self._limit_row = self.torque_limit[None]
        # arrays of the state are changed in place (the packed kernel arguments share them)
        self._fusion: tuple | bool | None = None  # see _fusion_arguments
        self._period: tuple | None = None  # see _period_arguments
        self._noise_draws: list = []

    def _timing(self, config: EnvConfig) -> tuple[float, float, int]:
        """(physics step, control period, physics steps per control period)."""
        physics = self.robot.physics_dt if config.physics_dt is None else config.physics_dt
        control = self.robot.control_dt if config.control_dt is None else config.control_dt
        return float(physics), float(control), substeps(control, physics)

    def _check_stability(self, plant: RobotModel) -> None:
        if not self.robot.elastic:
            return
        q = 0.5 * (np.asarray(self.robot.workspace_low) + np.asarray(self.robot.workspace_high))
        omega = plant.natural_frequencies(q)[0].max()
        if self.physics_dt * omega > STABILITY_LIMIT:
            raise ValueError(
                f"physics_dt={self.physics_dt} too coarse for the stiffest joint mode "
                f"({omega:.0f} rad/s): need physics_dt * omega <= {STABILITY_LIMIT}"
            )

    def _torque_limit(self, torque_limit) -> np.ndarray:
        if torque_limit is None:
            return np.asarray(self.robot.torque_limit, dtype=float)
        return per_joint_values(torque_limit, self.n_joints, "torque_limit", 0.0, strict=True)

    def _observation_space(self) -> spaces.Dict:
        n = self.n_joints
        inf = np.full(n, np.inf)
        entries: dict[str, spaces.Space] = {
            self.position_key: spaces.Box(-inf, inf, dtype=np.float64)
        }
        if self.model.n_sensors:
            r = np.full(3 * self.model.n_sensors, self.accelerometer_array.config.range)
            entries["acceleration"] = spaces.Box(-r, r, dtype=np.float64)
        entries["reference"] = spaces.Box(
            -np.full(2 * n, np.inf), np.full(2 * n, np.inf), dtype=np.float64
        )
        return spaces.Dict(entries)

    def limit_episode(self, steps: int) -> None:
        """Truncate episodes after ``steps`` control periods (instead of ``episode_time``)."""
        self.max_steps = int(steps)
        self.episode_time = self.max_steps * self.control_dt
        self._fusion = self._period = None  # the period's packed arguments hold the length

    @property
    def plant_model(self) -> RobotModel:
        """The exact model of arm 0's simulated plant (of every arm's when they share one)."""
        return self.sim.plants.models[0]

    @property
    def position_key(self) -> str:
        return "motor_position" if self.robot.elastic else "link_position"

    @property
    def time(self) -> np.ndarray:
        """Simulated time of each arm's episode (s), a copy."""
        return self._time.copy()

    # ------------------------------------------------------------------ episodes
    @contextlib.contextmanager
    def generators_kept_on_error(self, arms: np.ndarray, env: Any = None) -> Iterator[None]:
        """If the block raises (a refused reset), the generators of ``arms`` are the same
        objects in the same states as before it, and so is the ``np_random`` of ``env`` (a
        single-arm env) and its seed: a refused reset changes no stream."""
        saved = [(i, self.rngs[i], self.rngs[i].bit_generator.state) for i in arms]
        own = None if env is None else (env._np_random, env._np_random_seed)
        try:
            yield
        except BaseException:
            for i, rng, state in saved:
                rng.bit_generator.state = state
                self.rngs[i] = rng
            if own is not None:
                env._np_random, env._np_random_seed = own
            raise

    def reset_arms(self, arms: np.ndarray, options: dict | None = None) -> None:
        """Start new episodes for ``arms`` (indices) at rest, or at ``options["initial_state"]``.

        ``options["initial_state"]`` may give ``q`` and ``dq`` (and ``theta``, ``dtheta``
        for elastic arms; default: static equilibrium theta = q + K^-1 g(q)). The arms
        draw their episode from ``self.rngs``.
        """
        self._check_open()
        arms = np.asarray(arms, dtype=np.int64)
        given = self._initial_state_options(options)
        q0 = self.task.reset(arms, self.rngs)
        self.plant_state.reset(arms)
        q, dq, theta, dtheta = self._initial_state(q0, given, arms)
        self.sim.reset_state(arms, q, dq, theta, dtheta)
        self.accelerometer_array.reset(arms, self.rngs)
        self.encoder.restart(arms)
        self.steps[arms] = 0
        self._time[:] = self.steps * self.control_dt
        self.running[arms] = True
        self.reasons[arms] = None
        self.saturated[arms] = False
        self.torque[arms] = self._equilibrium_torque(q, theta, arms)
        self.previous_torque[arms] = self.torque[arms]
        self.plant_state.reset_commands(arms, self.torque[arms])
        self.ddq[arms] = self.sim.link_acceleration(self.torque)[arms]
        self.reference[arms] = self.task.reference(self._time[arms], arms)
        self._observe(arms, first=True)
        self._fusion = None  # the arms' sensors and plants may have changed

    def step(self, actions: np.ndarray, stepping: np.ndarray | None = None) -> tuple:
        """Advance every arm one control period under motor torques ``actions`` (N, n).

        ``stepping`` (bool (N,), default all): the arms whose episode advances; the others
        (about to be reset) are driven with zero torque and take no measurement, so their
        generators are untouched. Returns ``(reward, terminated, truncated)`` (N,) of the
        stepping arms (zero/False elsewhere); observations and info are in ``self.obs``
        and :meth:`info`.
        """
        self._check_open()
        every = stepping is None or bool(stepping.all())
        stepping = self._all if stepping is None else stepping
        command = actions if every else np.where(stepping[:, None], actions, 0.0)
        command = self.plant_state.delayed(command)
        pulse = self.plant_state.before_step(self._time)
        fusion = self._fusion if every and pulse is None else False
        if fusion is None:
            fusion = self._fusion = self._fusion_arguments()
        truncated = self._truncation()
        if isinstance(fusion, tuple) and fusion[3] is not None:  # the period in one call
            code, ended = _control_period_kernel(command, truncated, fusion[3])
            bullet_capi.raise_for(code)
        else:
            ended = self._period_step_by_step(command, pulse, every, stepping, truncated)
        self._slot = (self._slot + 1) % self._sensor_line
        reward, reasons = self._end_of_period(self._tau, pulse, fusion, every, stepping)
        return self._outcome(reward, reasons, truncated, ended, every, stepping)

    def _period_step_by_step(self, command, pulse, every: bool, stepping, truncated) -> bool:
        """What :func:`_control_period_kernel` does, call by call (a GUI world, torque
        pulses, arms that do not all step): returns whether an arm is truncated."""
        sim = self.sim
        external = self.task.external_torque(self._time, sim.q)
        if external is not None and not every:
            external = np.where(stepping[:, None], external, 0.0)
        tau = self._tau
        _clip_torque(command, external, self._minus_limit, self.torque_limit, tau, self.saturated)
        sim.step(tau, self.n_substeps, pulse)
        ended = _advance_clock(
            self.steps,
            None if every else stepping,
            self.control_dt,
            self.max_steps,
            self._time,
            truncated,
        )
        self.previous_torque[:] = self.torque
        self.torque[:] = tau
        self.reference[:] = self.task.reference(self._time)
        return ended

    def _truncation(self) -> np.ndarray:
        """A fresh array for the truncation flags (the shared False one without a length)."""
        return self._no_arm if self.max_steps is None else np.empty(self.n_arms, dtype=bool)

    def _outcome(self, reward, reasons, truncated, ended: bool, every: bool, stepping) -> tuple:
        """(reward, terminated, truncated) of the stepping arms (zero/False elsewhere) from
        the period's reward, termination reasons (None: no arm broke) and truncation; the
        reasons are kept and the ended episodes stop running."""
        if reasons is None:  # the common case: no arm broke its physics
            self.reasons = self._no_reasons
            terminated = self._no_arm
        else:
            terminated = (reasons != None) & stepping  # noqa: E711 - elementwise test
            self.reasons = np.where(stepping, reasons, np.array(None))
            reward = np.where(terminated, self.reward_config.termination_reward, reward)
            truncated = truncated & ~terminated
        if not every:
            reward = np.where(stepping, reward, 0.0)
            truncated = truncated & stepping
        if reasons is not None or ended:  # else no episode ended
            self.running &= ~(terminated | truncated)
        return reward, terminated, truncated

    def _end_of_period(self, tau, pulse, fusion: tuple | bool, every: bool, stepping: np.ndarray):
        """(reward, termination reasons or None) at the end of a control period: q'' and
        the accelerometers' noise-free readings, termination, measurements, reward; in one
        compiled call (:func:`_post_step_kernel`) where ``fusion`` (the batch's
        :meth:`_fusion_arguments`, or False) allows it."""
        sim = self.sim
        forces: np.ndarray | None
        reasons: np.ndarray | None
        if isinstance(fusion, tuple):
            packed, ddq, forces = fusion[:3]
            reward = np.empty(self.n_arms)
            for noise, std in self._noise_draws:  # the generators' blocks, in sensor order
                if std > 0.0:
                    noise.refill(self.rngs)
            finished = _post_step_kernel(
                tau, self.previous_torque, self.reference, self._slot, reward, packed
            )
            self.ddq = ddq
            if finished:
                return reward, None
            reasons = REASONS[self._codes]
        else:
            if self.model.n_sensors:  # q'' and the accelerometers' noise-free readings at once
                self.ddq, forces = sim.link_acceleration_and_forces(tau, pulse)
            else:
                self.ddq, forces = sim.link_acceleration(tau, pulse), None
            reasons = self._termination_reasons()
        self._observe(
            self._arms if every else np.flatnonzero(stepping),
            first=False,
            finite=reasons is None,
            forces=forces,
        )
        return self._reward(), reasons

    def _fusion_arguments(self) -> tuple | bool:
        """(the :class:`~elastic_gym.model.packed.Packed` arguments of
        :func:`_post_step_kernel` that hold for the episode, its q'' and accelerometer
        readings arrays, :meth:`_period_arguments`) (None in ``self._fusion``: not yet
        built; rebuilt after every reset), or False when the batch needs the step by step
        path: an arm with its own sensor error model, an accelerometer filter."""
        sim, encoder, acc = self.sim, self.encoder, self.accelerometer_array
        plants, n_sensors = sim.plants, self.model.n_sensors
        resolution, noise_std = encoder._shared
        sample_std, alpha, limit, acc_resolution = acc._shared
        if (
            resolution is None
            or noise_std is None
            or (
                n_sensors
                and (alpha != 0.0 or sample_std is None or limit is None or acc_resolution is None)
            )
        ):
            return False
        N, n = self.n_arms, self.n_joints
        shape = (N, n)
        ddq, forces = np.empty(shape), np.empty((N, 3 * n_sensors))
        transmission = (  # the transmission kernel's arguments after tau
            *plants.transmission,
            self.robot.elastic,
            np.empty(shape),
            np.empty(shape),
            np.empty(shape),
            0.0,
        )
        dynamics = plants.chain.dynamics_and_forces_arguments(ddq, forces)
        limits = (self.joint_lower, self.joint_upper, self.max_velocity, self._codes)
        size = 3 * n_sensors
        no_readings = self._no_readings
        obs, lines = self.obs, self._measured
        position = self.position_key
        sensors = (
            self.robot.elastic,
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
            self.sensor_delay,
            obs[position],
            obs["acceleration"] if n_sensors else no_readings,
            obs["reference"],
        )
        rewards = (self._limit_row, *self.reward_config.kernel_constants(self.control_dt))
        self._noise_draws = [(encoder.noise, noise_std)]
        if n_sensors:
            self._noise_draws.append((acc.noise, sample_std))
        state = (sim.theta, sim.dtheta, sim.q, sim.dq)
        coupling = sim.coupling_arguments()
        packed = Packed((*state, transmission, coupling, dynamics, limits, sensors, rewards))
        return packed, ddq, forces, self._period_arguments()

    def _period_arguments(self) -> Packed | None:
        """:func:`_control_period_kernel`'s ``packed``, or None where the simulator cannot
        step through PyBullet's C API or the task has no compiled form: the torque limits
        (low, high), the clipped torque, the saturation flags and the open-loop torque
        (outputs), the task's open-loop torque arguments, q, the simulator's
        :meth:`~elastic_gym.envs.simulator.ArmSimulator.period_arguments`, the substeps per
        period, the clock (steps, control period, episode length in periods or None,
        time), the torques (current, previous), the reference and the task's reference
        arguments (:meth:`~elastic_gym.envs.tasks.Task.compiled_arguments`).

        Packing costs about 0.35 ms (numba types the nested tuple in Python), so the pack
        is kept across resets, which change its arrays in place, and made again only when
        the simulator packed its own arguments again (new plants) or ``self._period`` was
        cleared (arrays replaced, a new episode length)."""
        sim = self.sim
        physics, task = sim.period_arguments(), self.task.compiled_arguments()
        if physics is None or task is None:
            return None
        if self._period is not None and self._period[0] == physics[2:4]:
            return self._period[1]
        task_torque, task_reference = task
        packed = Packed(
            (
                self._minus_limit,
                self.torque_limit,
                self._tau,
                self.saturated,
                self._external,
                task_torque,
                sim.q,
                physics,
                self.n_substeps,
                self.steps,
                self.control_dt,
                self.max_steps,
                self._time,
                self.torque,
                self.previous_torque,
                self.reference,
                task_reference,
            )
        )
        self._period = (physics[2:4], packed)
        return packed

    def _initial_state_options(self, options: dict | None) -> dict[str, np.ndarray]:
        """The reset ``options`` validated (types and angle magnitudes by their model, the
        lengths, velocities and joint limits here): the given initial state by key."""
        model: type[ElasticResetOptions | RigidResetOptions] = (
            ElasticResetOptions if self.robot.elastic else RigidResetOptions
        )
        given = validated(model, options, "options").initial_state
        n, values = self.n_joints, {}
        for key, value in ({} if given is None else given.model_dump(exclude_none=True)).items():
            speed = self.max_velocity if key.startswith("d") else None
            within = "" if speed is None else f" of magnitude <= {speed:g}"
            what = f"must be {n} numbers{within}"
            arr = numbers(value, f"options.initial_state.{key}:", what, [(n,)], bound=speed)
            if key == "q":
                self._check_within_limits("options.initial_state.q", arr)
            values[key] = arr
        return values

    def _initial_state(self, q0: np.ndarray, given: dict[str, np.ndarray], arms: np.ndarray):
        q = np.broadcast_to(given["q"], q0.shape).copy() if "q" in given else q0
        dq = np.broadcast_to(given.get("dq", np.zeros(self.n_joints)), q.shape).copy()
        if not self.robot.elastic:
            return q, dq, q, dq
        if "theta" in given:
            theta = np.broadcast_to(given["theta"], q.shape).copy()
        else:  # static equilibrium theta = q + K^-1 g(q)
            plants = self.sim.plants
            theta = q + plants.chain.select(arms).gravity(q) / plants.K[arms]
        dtheta = np.broadcast_to(given["dtheta"], q.shape).copy() if "dtheta" in given else dq
        return q, dq, theta, dtheta.copy()

    def _equilibrium_torque(self, q: np.ndarray, theta: np.ndarray, arms: np.ndarray) -> np.ndarray:
        """Motor torque that keeps a static state static (used for the reset reading)."""
        plants = self.sim.plants
        if self.robot.elastic:
            return plants.K[arms] * (theta - q)
        return plants.chain.select(arms).gravity(q)

    def _termination_reasons(self) -> np.ndarray | None:
        """Why each arm's physics broke (None entries where it did not), or None if no arm's."""
        sim = self.sim
        if not _break_codes(
            sim.q,
            sim.dq,
            sim.theta,
            sim.dtheta,
            self.joint_lower,
            self.joint_upper,
            self.max_velocity,
            self._codes,
        ):
            return None
        return REASONS[self._codes]

    def _observe(
        self,
        arms: np.ndarray,
        first: bool,
        finite: bool = True,
        forces: np.ndarray | None = None,
    ) -> None:
        """Measure the arms ``arms`` (their generators draw the noise), through the delay line.

        ``first``: the first reading of an episode fills the whole delay line; otherwise the
        reading goes to the newest slot (advanced by :meth:`step`). ``finite``: every arm's
        state is known to be finite (no need to look for readings to hold). ``forces``: the
        noise-free accelerometer readings of every arm (N, 3 n_sensors), if already known.
        """
        if not len(arms):
            return
        sim = self.sim
        every = arms is self._arms  # the hot path: whole arrays, no fancy indexing
        rows = slice(None) if every else arms
        rngs = self.rngs if every else [self.rngs[i] for i in arms]
        position = sim.theta if self.robot.elastic else sim.q
        readings = {self.position_key: self.encoder.measure(position[rows], rngs, arms)}
        if self.model.n_sensors:
            if forces is not None:
                force = forces if every else forces[arms]
            else:
                chain = sim.plants.chain
                chain = chain if every else chain.select(arms)
                force = chain.specific_forces(sim.q[rows], sim.dq[rows], self.ddq[rows])
            readings["acceleration"] = self.accelerometer_array.measure(force, rngs, arms)
        length = self._sensor_line
        if length > 1:
            oldest = (self._slot - self.sensor_delay[arms]) % length
        for key, value in readings.items():
            if length > 1:
                line = self._measured[key]
                if first:
                    line[:, rows] = value
                else:
                    line[self._slot, rows] = value
                value = line[oldest, arms]
            if not finite and not np.isfinite(value).all():  # a broken state keeps the last
                keep = ~np.isfinite(value).all(axis=1)  # reading
                value = np.where(keep[:, None], self.obs[key][rows], value)
            self.obs[key][rows] = value
        self.obs["reference"][rows] = self.reference[rows, :2].reshape(len(arms), -1)

    def _reward(self) -> np.ndarray:
        sim = self.sim
        return batch_reward(
            self.reward_config,
            self.control_dt,
            sim.q - self.reference[:, 0],
            sim.dq - self.reference[:, 1],
            self.torque,
            self.previous_torque,
            self.torque_limit,
            sim.theta - sim.q,
        )

    # ------------------------------------------------------------------ outputs
    def observation(self, arms: int | slice | np.ndarray = slice(None)) -> dict[str, np.ndarray]:
        """Copies of the current observations of ``arms`` (an int: one arm, no arm axis)."""
        return {key: value[arms].copy() for key, value in self.obs.items()}

    def info(self, arms: int | slice | np.ndarray = slice(None)) -> dict:
        """The info of ``arms`` (see the module docstring): arrays with a leading arm axis,
        or plain values of one arm when ``arms`` is an int.

        Every array is new (views of one fresh copy per group: the state, the reference),
        so no later step changes an info already handed out.
        """
        if isinstance(arms, (int, np.integer)):
            return self._arm_info(int(arms))
        sim, n = self.sim, self.n_joints
        # one fresh copy of the state and the reference (5 n each: the derivatives)
        x = np.concatenate(
            (
                sim.theta[arms],
                sim.q[arms],
                sim.dtheta[arms],
                sim.dq[arms],
                self.ddq[arms],
                self.reference[arms].reshape(-1, len(REFERENCE_KEYS) * n),
            ),
            axis=1,
        )
        state = {
            "q": x[:, n : 2 * n],
            "dq": x[:, 3 * n : 4 * n],
            "theta": x[:, :n],
            "dtheta": x[:, 2 * n : 3 * n],
            "ddq": x[:, 4 * n : 5 * n],
            "x": x[:, : 4 * n],
        }
        start = 5 * n
        return {
            "time": self._time[arms].copy(),
            "true_state": state,
            "torque": self.torque[arms].copy(),
            "torque_saturated": self.saturated[arms].copy(),
            "acceleration_saturated": self._acceleration_saturated(arms),
            "reference": {
                key: x[:, start + k * n : start + (k + 1) * n]
                for k, key in enumerate(REFERENCE_KEYS)
            },
            "termination_reason": self.reasons[arms].copy(),
            "plant": self.plant_state.info(arms),
        }

    def _arm_info(self, k: int) -> dict:
        """:meth:`info` of the one arm ``k`` (plain values; the same items, one compiled
        copy of the state, the reference and the torque)."""
        sim, n = self.sim, self.n_joints
        x = np.empty((6 + len(REFERENCE_KEYS)) * n)
        at_range = _arm_values(
            k,
            sim.theta,
            sim.q,
            sim.dtheta,
            sim.dq,
            self.ddq,
            self.reference,
            self.torque,
            self.obs.get("acceleration", self._no_readings),
            self.accelerometer_array.range,
            x,
        )
        return {
            "time": float(self._time[k]),
            "true_state": {
                "q": x[n : 2 * n],
                "dq": x[3 * n : 4 * n],
                "theta": x[:n],
                "dtheta": x[2 * n : 3 * n],
                "ddq": x[4 * n : 5 * n],
                "x": x[: 4 * n],
            },
            "torque": x[10 * n :],
            "torque_saturated": bool(self.saturated[k]),
            "acceleration_saturated": at_range,
            "reference": {  # REFERENCE_KEYS
                "q": x[5 * n : 6 * n],
                "dq": x[6 * n : 7 * n],
                "ddq": x[7 * n : 8 * n],
                "d3q": x[8 * n : 9 * n],
                "d4q": x[9 * n : 10 * n],
            },
            "termination_reason": self.reasons[k],
            "plant": self.plant_state.info(k),
        }

    def _acceleration_saturated(self, arms) -> np.ndarray:
        """Whether an observed accelerometer reading is at the sensor's range (clipped)."""
        if not self.model.n_sensors:
            return np.zeros(len(self._time[arms]), dtype=bool)
        readings = np.abs(self.obs["acceleration"][arms])
        limit = self.accelerometer_array.range[arms]
        return (readings >= limit[:, None]).any(axis=-1)

    def reference_preview(self, offsets: np.ndarray) -> np.ndarray:
        """q_d .. q_d^(4) of every arm at its time + each offset (s): (N, H, 5, n).

        The reference is the planner's trajectory, known in advance (not a measurement).
        """
        offsets = np.asarray(offsets, dtype=float).reshape(-1)
        time = self.time
        return np.stack([self.task.reference(time + h) for h in offsets], axis=1)

    def render(self, arm: int = 0) -> np.ndarray:
        self._check_open()
        return self.sim.render(arm)

    # ------------------------------------------------------------------ lifetime
    def _check_open(self) -> None:
        if not self.sim.connected:
            raise RuntimeError("the env is closed: its PyBullet client is gone; make a new env")

    @property
    def closed(self) -> bool:
        return not self.sim.connected

    def close(self) -> None:
        self.sim.close()

    def _noise_streams(self) -> tuple:
        return self.encoder.noise, self.accelerometer_array.noise

    def __getstate__(self) -> dict:
        """Constructor arguments + the state of every arm (a PyBullet client cannot be
        pickled). Unpickling builds an independent batch with its own client in the same
        state: it continues bit for bit like the original."""
        if self.closed:
            raise RuntimeError("cannot pickle a closed env")
        sim = self.sim
        episode = {
            "sim": (sim.q, sim.dq, sim.theta, sim.dtheta),
            "arrays": {
                key: getattr(self, key)
                for key in (
                    "steps",
                    "_time",
                    "running",
                    "torque",
                    "previous_torque",
                    "saturated",
                    "ddq",
                    "reference",
                    "reasons",
                    "obs",
                    "_measured",
                    "_slot",
                )
            },
            "rngs": [rng.bit_generator.state for rng in self.rngs],
            "plant_rngs": [None if r is None else r.bit_generator.state for r in self.plant_rngs],
            "plants": (list(self.settings), self.plant_state.__getstate__()),
            "accelerometer": (
                self.accelerometer_array.bias,
                self.accelerometer_array.filtered,
                self.accelerometer_array.fresh,
            ),
            "noise": [(noise.block, noise.next) for noise in self._noise_streams()],
            "task": {k: v for k, v in vars(self.task).items() if k not in ("spec", "model")},
        }
        return {"init": self.init_kwargs, "episode": episode}

    def _restore_plants(self, settings: list, plant_state: dict, plant_rngs: list) -> None:
        """The drawn plants, payload masses and plant streams of a pickled batch."""
        for arm, (arm_settings, original) in enumerate(zip(settings, self.settings, strict=True)):
            if arm_settings != original:
                self.plant_state.apply(arm, arm_settings)
        for arm, mass in enumerate(plant_state["payload_mass"]):
            if mass != self.plant_state.payload_mass[arm]:
                self.sim.plants.set(arm, self.resolver.plant_model(settings[arm], mass))
                self.sim.set_payload_mass(arm, mass)
        vars(self.plant_state).update(plant_state)
        for arm, rng_state in enumerate(plant_rngs):
            if rng_state is not None:
                rng = np.random.default_rng()
                rng.bit_generator.state = rng_state
                self.plant_rngs[arm] = rng
                self._plant_sources[arm] = self.rngs[arm]

    def __setstate__(self, state: dict) -> None:
        type(self).__init__(self, **state["init"])
        episode = state["episode"]
        self.sim.reset_state(np.arange(self.n_arms), *episode["sim"])
        for key, value in episode["arrays"].items():
            setattr(self, key, value)
        for rng, rng_state in zip(self.rngs, episode["rngs"], strict=True):
            rng.bit_generator.state = rng_state
        settings, plant_state = episode["plants"]
        self._restore_plants(settings, plant_state, episode["plant_rngs"])
        acc = self.accelerometer_array
        acc.bias, acc.filtered, acc.fresh = episode["accelerometer"]
        for noise, (block, following) in zip(self._noise_streams(), episode["noise"], strict=True):
            noise.block, noise.next = block, following
        vars(self.task).update(episode["task"])
        self._fusion = self._period = None  # arrays replaced
