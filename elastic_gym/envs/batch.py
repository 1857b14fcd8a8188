"""N arms of one robot in one PyBullet world: the simulation core of every env.

`ArmBatch` runs the episodes of N arms at once, every quantity in arrays with a leading arm
axis, as the orchestration of a control period over parts that each own their state (see
`ArmBatch`). [`ArmEnv`][elastic_gym.envs.arm_env.ArmEnv] is its N = 1 case and
[`ArmVectorEnv`][elastic_gym.envs.vector_env.ArmVectorEnv] exposes all N arms as a
Gymnasium vector env; there is no second copy of the physics.

Exactness: arm i draws every random number from its own generator (its plant from its own
plant stream), and every computation on it depends only on its own rows, with the same
operations in the same order whatever N. So arm i of a batch seeded s + i is bit for bit
the single env reset with seed s + i under the same actions, and with `per_arm` the single
env made with arm i's merged kwargs. The observation holds only what a real arm measures;
the truth, the applied torque, the reference and the plant's own parameters are in `info`.
"""

from __future__ import annotations

import contextlib
import operator
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np
from gymnasium import spaces

from elastic_gym.envs import bullet_capi, snapshot
from elastic_gym.envs.arm_config import ArmResolver
from elastic_gym.envs.batch_setup import (
    check_within_limits,
    observation_shapes,
    plan_arms,
    timing,
    torque_limits,
)
from elastic_gym.envs.config import EnvConfig
from elastic_gym.envs.episode import EpisodeState
from elastic_gym.envs.info import BatchInfo
from elastic_gym.envs.initial_state import equilibrium_torque, initial_state, initial_state_options
from elastic_gym.envs.kernels import control_period_kernel
from elastic_gym.envs.measurement import Sensors
from elastic_gym.envs.memory import check_batch_memory
from elastic_gym.envs.packing import Fused, FusedArguments
from elastic_gym.envs.plant import PlantArray
from elastic_gym.envs.plant_state import PlantState
from elastic_gym.envs.reward import RewardConfig, batch_reward
from elastic_gym.envs.sensors import every_arm
from elastic_gym.envs.simulator import ArmSimulator
from elastic_gym.envs.tasks import make_task
from elastic_gym.model import RobotModel
from elastic_gym.robots.catalog import get_robot
from elastic_gym.robots.spec import RobotSpec
from elastic_gym.robots.urdf_tools import joint_limits
from elastic_gym.validation import checked_count, validated

FLOAT64 = np.dtype(np.float64)


def _float64_matrix(values: np.ndarray) -> bool:
    """Whether ``values`` is a C-contiguous, writeable float64 matrix: the torques a
    kernel's entry point (`Fused.period_call`) takes without numba's dispatch."""
    if type(values) is not np.ndarray or values.dtype is not FLOAT64 or values.ndim != 2:
        return False
    flags = values.flags
    return flags.c_contiguous and flags.writeable


def _view(part: str, name: str, doc: str) -> Any:
    """A read-only attribute of `ArmBatch` reading `name` of its part `part` (the arrays are
    the part's own: read them, change them through the part)."""
    return property(operator.attrgetter(f"{part}.{name}"), doc=doc)


class ArmBatch:
    """N arms of a robot of the catalog: simulation, sensors, task, reward, termination.

    The batch orchestrates a control period; each of its parts owns its state and is changed
    only through its own methods:

    * the simulator ([`simulator`][elastic_gym.envs.simulator]): the PyBullet world, theta, q,
      theta', q', the plants' constants, the physics substeps;
    * the plant state ([`plant_state`][elastic_gym.envs.plant_state]): each arm's settings,
      randomization draws, payloads, torque pulses, sensor and actuator delays;
    * the sensors ([`measurement`][elastic_gym.envs.measurement]): encoders and accelerometers
      (noise blocks, biases, filters);
    * the episode ([`episode`][elastic_gym.envs.episode]): clock, torques, q'', reference,
      termination, observation and the sensor delay line;
    * the task ([`tasks`][elastic_gym.envs.tasks]): reference trajectories, open-loop torques;
    * the fused kernels ([`kernels`][elastic_gym.envs.kernels]) and their packed arguments
      ([`packing`][elastic_gym.envs.packing]): a control period in two compiled calls;
    * the info ([`info`][elastic_gym.envs.info]) and pickling
      ([`snapshot`][elastic_gym.envs.snapshot]) read the parts (a snapshot is restored by each
      part itself).

    What needs the robot to be checked (timing, torque limits, each arm's plant and its
    stability) is resolved first ([`batch_setup`][elastic_gym.envs.batch_setup]).

    Args:
        robot: robot name (`elastic_gym.robots.catalog.ROBOTS`) or a `RobotSpec`.
        n_arms: number of arms (N).
        config: the env kwargs, an [`EnvConfig`][elastic_gym.envs.config.EnvConfig] (or a
            mapping of its fields, validated here; None: the defaults), whose docstring
            says what each option sets. What needs the robot is checked here: joint counts,
            sensor links, delays, friction in fractions of the torque limits, and a
            physics step fine enough for the stiffest joint mode (`physics_dt * omega_max
            <= 0.2`, every plant a `randomize` range can reach included).
        gui: show the PyBullet GUI (render_mode="human").

    `info["plant"]` is a flat mapping path -> value of the simulated plant's own
    parameters: `actuator_delay`, `payload.mass` (0 without a payload, the current
    mass after a change), `torque_pulse` (the link torque of the last control period),
    the pulse schedule `torque_pulses.times` / `.durations` / `.amplitudes` when an
    arm has pulses (padded with NaN to the batch's largest pulse count) and every
    randomized path's drawn value (NaN for an arm that does not randomize it).
    """

    def __init__(
        self,
        robot: str | RobotSpec,
        n_arms: int = 1,
        config: EnvConfig | Mapping[str, Any] | None = None,
        gui: bool = False,
    ) -> None:
        n_arms = checked_count(n_arms, "the number of arms", 1)
        config = validated(EnvConfig, config)
        spec = robot if isinstance(robot, RobotSpec) else get_robot(robot)
        check_batch_memory(spec.urdf, n_arms, spec.name)  # PyBullet would segfault
        self._arguments = (robot, n_arms, config, gui)
        self.config = config
        self.robot, self.n_arms, self.n_joints = spec, n_arms, spec.n_joints
        self.physics_dt, self.control_dt, self.n_substeps = timing(spec, config)
        mounts = spec.accelerometers if config.accelerometers is None else (*config.accelerometers,)
        self.torque_limit = torque_limits(spec, config.torque_limit)
        self.model = RobotModel(spec, accelerometers=mounts)
        self.resolver = ArmResolver(spec, mounts, self.torque_limit, self.control_dt)
        plans = plan_arms(self.resolver, config, n_arms, self.physics_dt)
        self.max_velocity, self.episode_time = config.max_velocity, config.episode_time
        max_steps = (
            None
            if self.episode_time is None
            else max(1, round(self.episode_time / self.control_dt))
        )
        self.joint_lower, self.joint_upper = joint_limits(spec.urdf, spec.joint_names)
        self.reward_config = RewardConfig.from_config(config.reward)
        self.task = make_task(config.task, spec, self.model, config.task_options, n_arms=n_arms)
        for name, points in self.task.configured_points().items():
            check_within_limits(f"task_options.{name}", points, *self._joint_limits)
        self.sensors = Sensors(
            plans.settings, self.n_joints, self.model.n_sensors, self.control_dt, spec.elastic
        )
        self.single_observation_space = self.sensors.observation_space()
        self.single_action_space = spaces.Box(
            -self.torque_limit, self.torque_limit, dtype=np.float64
        )
        self.sim = ArmSimulator(
            spec,
            PlantArray(plans.models),
            self.physics_dt,
            n_arms,
            gui=gui,
            payload_positions=[self.resolver.payload_position(s) for s in plans.settings],
            integrator=config.integrator,
            substeps=self.n_substeps,
        )
        self.rngs = [np.random.default_rng() for _ in range(n_arms)]
        self.plant_state = PlantState(
            plans.settings,
            plans.ranges,
            plans.arm_kwargs,
            self.resolver,
            self.torque_limit,
            self.sim,
            self.sensors,
        )
        self.episode = EpisodeState(
            n_arms,
            self.n_joints,
            self.control_dt,
            max_steps,
            observation_shapes(self.single_observation_space),
            self.sensors.position_key,
            self.plant_state.sensor_delay,
            self.plant_state.sensor_line,
        )
        self.fused = FusedArguments(
            self.sim,
            self.task,
            self.sensors,
            self.episode,
            self.torque_limit,
            self._joint_limits,
            self.max_velocity,
            self.reward_config.kernel_constants(self.control_dt),
            self.n_substeps,
        )
        self._quick: Fused | None = None  # see `_quick_path`
        self._quick_known = False
        self._info = BatchInfo(self.sim, self.episode, self.sensors, self.plant_state)
        self.arm_outputs = self._info.arm_outputs
        """(`observation`, `info`) of one arm in one compiled copy (their arrays views of
        one new array): what a single env's step returns
        ([`BatchInfo.arm_outputs`][elastic_gym.envs.info.BatchInfo.arm_outputs])."""
        self._all = np.ones(n_arms, dtype=bool)
        self._arms = every_arm(n_arms)  # (the sensors' whole-array path)
        self._minus_limit = -self.torque_limit
        self._termination_reward = self.reward_config.termination_reward

    # ------------------------------------------------------------------ read-only views
    @property
    def _joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        return self.joint_lower, self.joint_upper

    @property
    def plant_model(self) -> RobotModel:
        """The exact model of arm 0's simulated plant (of every arm's when they share one)."""
        return self.sim.plants.models[0]

    @property
    def position_key(self) -> str:
        """The observation key of the encoders (`motor_position` or `link_position`)."""
        return self.sensors.position_key

    encoder = _view("sensors", "encoder", "The position encoders of every arm.")
    accelerometer_array = _view("sensors", "accelerometer_array", "The accelerometers.")
    settings = _view("plant_state", "settings", "Each arm's current plant and sensor settings.")
    max_steps = _view("episode", "max_steps", "Episode length in control periods, or None.")
    running = _view("episode", "running", "Whether each arm's episode is under way (N,).")
    steps = _view("episode", "steps", "Control periods since each arm's reset (N,).")
    torque = _view("episode", "torque", "The applied motor torque of the last period (N, n).")
    previous_torque = _view("episode", "previous_torque", "The one before it (N, n).")
    saturated = _view("episode", "saturated", "Whether each arm's last action was clipped.")
    ddq = _view("episode", "ddq", "The true q'' at the end of the last period (N, n).")
    reference = _view("episode", "reference", "q_d .. q_d^(4) at each arm's time (N, 5, n).")
    reasons = _view("episode", "reasons", "Why each arm's episode was terminated (N,).")
    obs = _view("episode", "obs", "The current observation of every arm by key.")

    @property
    def time(self) -> np.ndarray:
        """Simulated time of each arm's episode (s), a copy."""
        return self.episode.time.copy()

    def limit_episode(self, steps: int) -> None:
        """Truncate episodes after `steps` control periods (instead of `episode_time`)."""
        self.episode.limit(int(steps))
        self.episode_time = int(steps) * self.control_dt
        self.fused.forget_period()  # the period's packed arguments hold the length
        self._quick_known = False

    # ------------------------------------------------------------------ episodes
    def set_generator(self, arm: int, generator: np.random.Generator) -> None:
        """Arm `arm` draws its next episodes from `generator` (an env's seeded one)."""
        self.rngs[arm] = generator

    @contextlib.contextmanager
    def generators_kept_on_error(self, arms: np.ndarray) -> Iterator[None]:
        """If the block raises (a refused reset), the generators of `arms` are the same
        objects in the same states as before it: a refused reset changes no stream."""
        saved = [(i, self.rngs[i], self.rngs[i].bit_generator.state) for i in arms]
        try:
            yield
        except BaseException:
            for i, rng, state in saved:
                rng.bit_generator.state = state
                self.rngs[i] = rng
            raise

    def reset_arms(self, arms: np.ndarray, options: dict | None = None) -> None:
        """Start new episodes for `arms` (indices) at rest, or at `options["initial_state"]`.

        `options["initial_state"]` may give `q` and `dq` (and `theta`, `dtheta` for
        elastic arms; default: static equilibrium theta = q + K^-1 g(q)). The arms draw
        their episode from `self.rngs`.
        """
        self.check_open()
        arms = np.asarray(arms, dtype=np.int64)
        sim, episode, elastic = self.sim, self.episode, self.robot.elastic
        given = initial_state_options(
            options, elastic, self.n_joints, self.max_velocity, self._joint_limits
        )
        q0 = self.task.reset(arms, self.rngs)
        self.plant_state.reset(arms, self.rngs)
        q, dq, theta, dtheta = initial_state(q0, given, arms, sim.plants, elastic)
        sim.reset_state(arms, q, dq, theta, dtheta)
        self.sensors.reset(arms, self.rngs)
        episode.begin(arms, equilibrium_torque(q, theta, arms, sim.plants, elastic))
        self.plant_state.reset_commands(arms, episode.torque[arms])
        episode.set_accelerations(arms, sim.link_acceleration(episode.torque)[arms])
        episode.set_reference(arms, self.task.reference(episode.time[arms], arms))
        self._observe(arms, first=True)
        self.fused.invalidate()  # the arms' sensors and plants may have changed
        self._quick_known = False

    def end_episodes(self, arms: np.ndarray) -> None:
        """End the episodes of `arms` now (a wrapper terminated them)."""
        self.episode.end(arms)

    def step(self, actions: np.ndarray, stepping: np.ndarray | None = None) -> tuple:
        """Advance every arm one control period under motor torques `actions` (N, n).

        `stepping` (bool (N,), default all): the arms whose episode advances; the others
        (about to be reset) are driven with zero torque and take no measurement, so their
        generators are untouched. Returns `(reward, terminated, truncated)` (N,) of the
        stepping arms (zero/False elsewhere); observations and info are in `observation`
        and `info`.

        A period runs in two compiled calls where it can (`control_period_kernel`,
        `post_step_kernel` of [`kernels`][elastic_gym.envs.kernels]), otherwise call by
        call (a GUI world, torque pulses, arms that do not all step, per-arm sensor error
        models): bit for bit the same.
        """
        self.check_open()
        if stepping is None:  # the common case: every arm, nothing but the kernels to run
            quick = self._quick if self._quick_known else self._quick_path()
            if quick is not None and _float64_matrix(actions):
                return self._fused_step(actions, quick)
        every = stepping is None or bool(stepping.all())
        stepping = self._all if stepping is None else stepping
        command = actions if every else np.where(stepping[:, None], actions, 0.0)
        plant, episode = self.plant_state, self.episode
        if plant.quiet:  # the common case: no delay line, payload change or pulse
            pulse = None
        else:
            command = plant.delayed(command)
            pulse = plant.before_step(episode.time)
        fused = self.fused.get() if every and pulse is None else None
        truncated = episode.truncation()
        if fused is not None and fused.period is not None:  # the period in one call
            call = fused.period_call if _float64_matrix(command) else control_period_kernel
            code, ended = call(command, truncated, *fused.period)
            if code != bullet_capi.OK:
                bullet_capi.raise_for(code)
        else:
            ended = self._period_step_by_step(command, pulse, every, stepping, truncated)
        episode.next_slot()
        reward, reasons = self._end_of_period(pulse, fused, every, stepping)
        return episode.conclude(
            reward, reasons, truncated, ended, every, stepping, self._termination_reward
        )

    def _quick_path(self) -> Fused | None:
        """The fused arguments when a period of every arm is the two compiled calls and
        nothing else (no delay line, payload change or pulse: `PlantState.quiet`; the
        period's pack), else None; kept until the next reset (which may change both)."""
        fused = self.fused.get()
        if fused is None or fused.period is None or not self.plant_state.quiet:
            fused = None
        self._quick, self._quick_known = fused, True
        return fused

    def _fused_step(self, actions: np.ndarray, fused: Fused) -> tuple:
        """`step` of every arm when a period is the two compiled calls and nothing else
        (no delay line, payload change or pulse; the fused arguments; C-contiguous float64
        actions): the general path's calls in its order, bit for bit the same."""
        episode = self.episode
        truncated = episode.truncation()
        period = fused.period  # not None on the quick path (`_quick_path`)
        code, ended = fused.period_call(actions, truncated, *period)  # type: ignore[misc]
        if code != bullet_capi.OK:
            bullet_capi.raise_for(code)
        episode.next_slot()
        reward, reasons = self._fused_end(fused)
        return episode.conclude(
            reward, reasons, truncated, ended, True, self._all, self._termination_reward
        )

    def _period_step_by_step(self, command, pulse, every: bool, stepping, truncated) -> bool:
        """What `control_period_kernel` does, call by call: returns whether an arm is
        truncated."""
        sim, episode = self.sim, self.episode
        external = self.task.external_torque(episode.time, sim.q)
        if external is not None and not every:
            external = np.where(stepping[:, None], external, 0.0)
        tau = episode.clip(command, external, self._minus_limit, self.torque_limit)
        sim.step(tau, self.n_substeps, pulse)
        ended = episode.advance(None if every else stepping, truncated)
        episode.set_reference(slice(None), self.task.reference(episode.time))
        return ended

    def _end_of_period(
        self, pulse, fused: Fused | None, every: bool, stepping: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """(reward, termination reasons or None) at the end of a control period: q'' and
        the accelerometers' noise-free readings, termination, measurements, reward; in one
        compiled call (`post_step_kernel`) with the episode's `fused` arguments."""
        if fused is not None:  # (every arm steps)
            return self._fused_end(fused)
        sim, episode = self.sim, self.episode
        forces: np.ndarray | None
        if self.model.n_sensors:  # q'' and the accelerometers' noise-free readings at once
            ddq, forces = sim.link_acceleration_and_forces(episode.clipped, pulse)
        else:
            ddq, forces = sim.link_acceleration(episode.clipped, pulse), None
        episode.set_accelerations(slice(None), ddq)
        reasons = episode.termination_reasons(
            sim.q, sim.dq, sim.theta, sim.dtheta, *self._joint_limits, self.max_velocity
        )
        self._observe(
            self._arms if every else np.flatnonzero(stepping),
            first=False,
            finite=reasons is None,
            forces=forces,
        )
        return self._reward(), reasons

    def _fused_end(self, fused: Fused) -> tuple[np.ndarray, np.ndarray | None]:
        """`_end_of_period` of every arm with the episode's `fused` arguments:
        `post_step_kernel`, or, where an arm broke its physics, the measurement with the
        hold of non-finite readings and the reward."""
        episode = self.episode
        reward = np.empty(self.n_arms)
        fused.refill(self.rngs)
        tau, previous, reference = episode.clipped, episode.previous_torque, episode.reference
        if fused.end_call(
            tau, previous, reference, episode.slot, reward, fused.coupling, fused.end
        ):
            return reward, None
        return self._broken_end(fused)

    def _broken_end(self, fused: Fused) -> tuple[np.ndarray, np.ndarray]:
        """The end of a period where `post_step_kernel` found an arm's physics broken:
        the measurement with the hold of non-finite readings, the reward, the reasons."""
        reasons = self.episode.broken()
        self._observe(self._arms, first=False, finite=False, forces=fused.forces)
        return self._reward(), reasons

    def _observe(
        self, arms: np.ndarray, first: bool, finite: bool = True, forces: np.ndarray | None = None
    ) -> None:
        """Measure the arms `arms` (their generators draw the noise) into the observation,
        through the delay line (`EpisodeState.record`: `first`, `finite`). `forces`: the
        noise-free accelerometer readings of every arm, if already known."""
        if not len(arms):
            return
        every = arms is self._arms  # the hot path: whole arrays, no fancy indexing
        readings = self.sensors.read(self.sim, self.episode.ddq, arms, every, self.rngs, forces)
        self.episode.record(arms, every, readings, first, finite)

    def _reward(self) -> np.ndarray:
        sim, episode = self.sim, self.episode
        return batch_reward(
            self.reward_config,
            self.control_dt,
            sim.q - episode.reference[:, 0],
            sim.dq - episode.reference[:, 1],
            episode.torque,
            episode.previous_torque,
            self.torque_limit,
            sim.theta - sim.q,
        )

    # ------------------------------------------------------------------ outputs
    def observation(self, arms: int | slice | np.ndarray = slice(None)) -> dict[str, np.ndarray]:
        """Copies of the current observations of `arms` (an int: one arm, no arm axis)."""
        return {key: value[arms].copy() for key, value in self.episode.obs.items()}

    def info(self, arms: int | slice | np.ndarray = slice(None)) -> dict:
        """The info of `arms` ([`BatchInfo`][elastic_gym.envs.info.BatchInfo]): arrays with
        a leading arm axis, or plain values of one arm when `arms` is an int. Every array
        is new: no later step changes an info already handed out."""
        if isinstance(arms, (int, np.integer)):
            return self._info.arm(int(arms))
        return self._info.arms(arms)

    def reference_preview(self, offsets: np.ndarray) -> np.ndarray:
        """q_d .. q_d^(4) of every arm at its time + each offset (s): (N, H, 5, n).

        The reference is the planner's trajectory, known in advance (not a measurement).
        """
        offsets = np.asarray(offsets, dtype=float).reshape(-1)
        time = self.time
        return np.stack([self.task.reference(time + h) for h in offsets], axis=1)

    def render(self, arm: int = 0) -> np.ndarray:
        self.check_open()
        return self.sim.render(arm)

    # ------------------------------------------------------------------ lifetime
    def check_open(self) -> None:
        """Refuse to work on a closed batch (its PyBullet client is gone)."""
        if not self.sim.connected:
            raise RuntimeError("the env is closed: its PyBullet client is gone; make a new env")

    @property
    def closed(self) -> bool:
        return not self.sim.connected

    def close(self) -> None:
        self.sim.close()

    # ------------------------------------------------------------------ pickling
    def _parts(self) -> snapshot.Parts:
        return snapshot.Parts(
            self.sim, self.episode, self.plant_state, self.sensors, self.task, self.rngs
        )

    def __getstate__(self) -> dict:
        """Constructor arguments + a snapshot of every part's state
        ([`snapshot`][elastic_gym.envs.snapshot]; a PyBullet client cannot be pickled).
        Unpickling builds an independent batch with its own client in the same state: it
        continues bit for bit like the original."""
        if self.closed:
            raise RuntimeError("cannot pickle a closed env")
        return {"init": self._arguments, "episode": snapshot.capture(self._parts())}

    def __setstate__(self, state: dict) -> None:
        type(self).__init__(self, *state["init"])
        snapshot.restore(self._parts(), state["episode"])
        self.fused.forget_period()  # the task's arrays were replaced
        self._quick_known = False
