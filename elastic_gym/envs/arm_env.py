"""Gymnasium environments of arms with elastic (or rigid) joints and realistic sensing.

Observation (a ``spaces.Dict``, float64), only what a real arm measures:

* elastic arms: ``motor_position`` (N, quantized motor encoders), ``acceleration``
  (3 per accelerometer: specific force in the sensor frame, gravity included),
  ``reference`` (q_d, q_d');
* rigid arms: ``link_position`` (N, link encoders), ``reference``.

No link position and no velocity of an elastic arm is ever observed; the ground
truth is in ``info["true_state"]``. Action: motor torque (N m), clipped to the torque
limits (``info["torque_saturated"]``).

Reward: :mod:`elastic_gym.envs.reward` (bounded tracking kernels, torque and torque-rate
penalties, every step >= 0). An episode whose physics breaks (non-finite state, a
velocity above ``max_velocity``, or a link position beyond the URDF joint limits) ends
with ``terminated=True``, the reward's (negative) termination reward and
``info["termination_reason"]``.
"""

from __future__ import annotations

from collections import deque
from typing import ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from elastic_gym.envs.reward import RewardConfig, total_reward
from elastic_gym.envs.sensors import (
    AccelerometerArray,
    AccelerometerConfig,
    Encoder,
    EncoderConfig,
)
from elastic_gym.envs.simulator import ArmSimulator
from elastic_gym.envs.tasks import make_task
from elastic_gym.model import ParameterScaling, RobotModel
from elastic_gym.robots.catalog import get_robot
from elastic_gym.robots.spec import AccelerometerMount, RobotSpec
from elastic_gym.robots.urdf_tools import joint_limits
from elastic_gym.validation import per_joint_values

STABILITY_LIMIT = 0.2  # largest admissible physics_dt * omega_max


class ArmEnv(gym.Env):
    """An arm of the catalog in PyBullet with sensors, a task and a nominal model.

    Args:
        robot: robot name (``elastic_gym.robots.catalog.ROBOTS``) or a ``RobotSpec``.
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
        torque_limit: override of the motor torque limits (N m).
        reward: weights and scales of the reward, see
            :class:`~elastic_gym.envs.reward.RewardConfig` (also the termination reward).
        max_velocity: |q'| or |theta'| above this ends the episode (rad/s).
        sensor_delay: measurement delay in control periods (encoders and accelerometers;
            the reference is not delayed).
        render_mode: ``"rgb_array"`` or ``"human"``.
    """

    metadata: ClassVar[dict] = {"render_modes": ["human", "rgb_array"], "render_fps": 30}

    def __init__(
        self,
        robot: str | RobotSpec,
        task: str = "tracking",
        task_options: dict | None = None,
        physics_dt: float | None = None,
        control_dt: float | None = None,
        encoder: dict | EncoderConfig | None = None,
        accelerometer: dict | AccelerometerConfig | str | None = None,
        accelerometers: list | None = None,
        plant_scaling: dict | ParameterScaling | None = None,
        torque_limit: list | None = None,
        reward: dict | RewardConfig | None = None,
        max_velocity: float = 100.0,
        sensor_delay: int = 0,
        render_mode: str | None = None,
    ) -> None:
        self._init_kwargs = {k: v for k, v in locals().items() if k not in ("self", "__class__")}
        spec = robot if isinstance(robot, RobotSpec) else get_robot(robot)
        self.robot = spec
        n = spec.n_joints
        self.n_joints = n
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode {render_mode!r} not supported; valid: {self.metadata['render_modes']}"
            )
        self.render_mode = render_mode

        self.physics_dt, self.control_dt, self.n_substeps = self._timing(physics_dt, control_dt)
        mounts = spec.accelerometers if accelerometers is None else tuple(
            AccelerometerMount.from_config(m) for m in accelerometers
        )
        self.model = RobotModel(spec, accelerometers=mounts)
        self.plant_model = RobotModel(spec, plant_scaling, mounts)
        self._check_stability()
        self.torque_limit = self._torque_limit(torque_limit)
        self.max_velocity = float(max_velocity)
        if not isinstance(sensor_delay, int) or isinstance(sensor_delay, bool) or sensor_delay < 0:
            raise ValueError(f"sensor_delay must be an integer >= 0 (control periods), "
                             f"got {sensor_delay!r}")
        self.sensor_delay = sensor_delay
        self._sensor_queue: deque[dict[str, np.ndarray]] = deque(maxlen=sensor_delay + 1)
        self.joint_lower, self.joint_upper = joint_limits(spec.urdf, spec.joint_names)
        limits = np.concatenate([self.joint_lower, self.joint_upper])
        self._limited = bool(np.isfinite(limits).any())
        self.reward_config = RewardConfig.from_config(reward)
        self.task = make_task(task, spec, self.model, task_options)

        encoder_cfg = EncoderConfig.from_config(encoder)
        self.encoder = Encoder(
            spec.encoder_resolution if encoder_cfg.resolution is None else encoder_cfg.resolution,
            spec.encoder_noise_std if encoder_cfg.noise_std is None else encoder_cfg.noise_std,
        )
        accel_cfg = (
            AccelerometerConfig.ideal() if accelerometer == "ideal"
            else AccelerometerConfig.from_config(accelerometer)
        )
        self.accelerometer_array = AccelerometerArray(
            accel_cfg, self.model.n_sensors, self.control_dt
        )

        self.metadata = {
            **self.metadata,
            "physics_dt": self.physics_dt,
            "control_dt": self.control_dt,
            "robot": spec.name,
            "task": self.task.name,
        }
        self.action_space = spaces.Box(-self.torque_limit, self.torque_limit, dtype=np.float64)
        self.observation_space = self._observation_space()

        self.sim = ArmSimulator(spec, self.plant_model, self.physics_dt, gui=render_mode == "human")
        self.time = 0.0
        self._needs_reset = True
        self._last_obs: dict[str, np.ndarray] | None = None
        self._last_torque = np.zeros(n)

    # ------------------------------------------------------------------ setup
    def _timing(self, physics_dt, control_dt) -> tuple[float, float, int]:
        physics = self.robot.physics_dt if physics_dt is None else physics_dt
        control = self.robot.control_dt if control_dt is None else control_dt
        for key, value in (("physics_dt", physics), ("control_dt", control)):
            if not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
                raise ValueError(f"{key} must be a positive number, got {value!r}")
        if physics > 1e-3 + 1e-15:
            raise ValueError(f"physics_dt must be <= 1 ms, got {physics}")
        ratio = control / physics
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            raise ValueError(
                f"control_dt ({control}) must be an integer multiple of physics_dt ({physics})"
            )
        return float(physics), float(control), round(ratio)

    def _check_stability(self) -> None:
        if not self.robot.elastic:
            return
        q = 0.5 * (np.asarray(self.robot.workspace_low) + np.asarray(self.robot.workspace_high))
        omega = self.plant_model.natural_frequencies(q)[0].max()
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
        position_key = "motor_position" if self.robot.elastic else "link_position"
        entries = {position_key: spaces.Box(-inf, inf, dtype=np.float64)}
        if self.model.n_sensors:
            r = np.full(3 * self.model.n_sensors, self.accelerometer_array.config.range)
            entries["acceleration"] = spaces.Box(-r, r, dtype=np.float64)
        entries["reference"] = spaces.Box(-np.full(2 * n, np.inf), np.full(2 * n, np.inf),
                                          dtype=np.float64)
        return spaces.Dict(entries)

    # ------------------------------------------------------------------ API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode at rest (or at ``options["initial_state"]``).

        ``options["initial_state"]`` may give ``q`` and ``dq`` (and ``theta``,
        ``dtheta`` for elastic arms; default: static equilibrium theta = q + K^-1 g(q)).
        """
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"initial_state"}
        if unknown:
            raise ValueError(f"unknown reset option(s) {sorted(unknown)}; valid: ['initial_state']")
        q0 = self.task.reset(self.np_random)
        q, dq, theta, dtheta = self._initial_state(q0, options.get("initial_state"))
        self.sim.reset_state(q, dq, theta, dtheta)
        self.accelerometer_array.reset(self.np_random)
        self._sensor_queue.clear()
        self.time = 0.0
        self._needs_reset = False
        self._last_torque = self._equilibrium_torque(q, theta)
        ddq = self.sim.link_acceleration(self._last_torque)
        reference = self.task.reference(self.time)
        obs = self._observe(ddq, reference)
        info = self._info(ddq, self._last_torque, False, reference)
        return obs, info

    def step(self, action):
        tau_action = self._validate_action(action)
        if self._needs_reset:
            raise RuntimeError("call reset() before step() (and after an episode has ended)")
        sim = self.sim
        command = tau_action + self.task.external_torque(self.time, sim.q)
        tau = np.clip(command, -self.torque_limit, self.torque_limit)
        saturated = bool(np.any(tau != command))
        sim.step(tau, self.n_substeps)
        self.time += self.control_dt
        previous_torque, self._last_torque = self._last_torque, tau

        reason = self._termination_reason()
        if reason is not None:
            self._needs_reset = True
            info = {"time": self.time, "termination_reason": reason, "torque": tau.copy(),
                    "torque_saturated": saturated}
            last = {key: value.copy() for key, value in self._last_obs.items()}
            return last, self.reward_config.termination_reward, True, False, info
        ddq = sim.link_acceleration(tau)
        reference = self.task.reference(self.time)
        obs = self._observe(ddq, reference)
        reward = self._reward(tau, previous_torque, reference)
        info = self._info(ddq, tau, saturated, reference)
        if self.render_mode == "human":
            self.render()
        return obs, reward, False, False, info

    def render(self):
        if self.render_mode == "rgb_array":
            return self.sim.render()
        return None

    def close(self) -> None:
        if getattr(self, "sim", None) is not None:
            self.sim.close()

    # ------------------------------------------------------------------ pickling
    def __getstate__(self) -> dict:
        """Constructor arguments + the episode state (a PyBullet client cannot be pickled).

        Unpickling builds an independent env with its own client, in the same state: it
        continues bit for bit like the original (deep copies work the same way).
        """
        episode = None
        if not self._needs_reset:
            sim = self.sim
            episode = {
                "sim": (sim.q, sim.dq, sim.theta, sim.dtheta),
                "time": self.time,
                "last_torque": self._last_torque,
                "last_obs": self._last_obs,
                "rng": self.np_random.bit_generator.state,
                "accelerometer": (self.accelerometer_array.bias, self.accelerometer_array.filtered),
                "sensor_queue": list(self._sensor_queue),
                "task": {k: v for k, v in vars(self.task).items() if k not in ("spec", "model")},
            }
        return {"init": self._init_kwargs, "spec": getattr(self, "spec", None), "episode": episode}

    def __setstate__(self, state: dict) -> None:
        type(self).__init__(self, **state["init"])
        self.spec = state["spec"]
        episode = state["episode"]
        if episode is None:
            return
        self.sim.reset_state(*episode["sim"])
        self.time = episode["time"]
        self._last_torque = episode["last_torque"]
        self._last_obs = episode["last_obs"]
        self._np_random = np.random.Generator(np.random.PCG64())
        self._np_random.bit_generator.state = episode["rng"]
        self.accelerometer_array.bias, self.accelerometer_array.filtered = episode["accelerometer"]
        self._sensor_queue.extend(episode["sensor_queue"])
        vars(self.task).update(episode["task"])
        self._needs_reset = False

    # ------------------------------------------------------------------ internals
    def _validate_action(self, action) -> np.ndarray:
        arr = np.asarray(action)
        if arr.dtype.kind not in "fiu":
            raise TypeError(f"action must be a real numeric array, got dtype {arr.dtype}")
        if arr.shape != (self.n_joints,):
            raise ValueError(f"action must have shape ({self.n_joints},), got {arr.shape}")
        arr = arr.astype(np.float64)
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"action must be finite, got {arr}")
        return arr

    def _initial_state(self, q0: np.ndarray, given: dict | None):
        n = self.n_joints
        allowed = {"q", "dq", "theta", "dtheta"} if self.robot.elastic else {"q", "dq"}
        given = dict(given or {})
        unknown = set(given) - allowed
        if unknown:
            raise ValueError(
                f"unknown initial_state key(s) {sorted(unknown)}; valid: {sorted(allowed)}"
            )
        values = {}
        for key in given:
            arr = np.asarray(given[key], dtype=float)
            if arr.shape != (n,) or not np.all(np.isfinite(arr)):
                raise ValueError(f"initial_state[{key!r}] must be {n} finite numbers")
            values[key] = arr
        q = values.get("q", q0)
        dq = values.get("dq", np.zeros(n))
        if not self.robot.elastic:
            return q, dq, q, dq
        theta = values.get("theta", self.plant_model.static_motor_position(q))
        dtheta = values.get("dtheta", dq.copy())
        return q, dq, theta, dtheta

    def _equilibrium_torque(self, q: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Motor torque that keeps a static state static (used for the reset reading)."""
        if self.robot.elastic:
            return self.plant_model.K * (theta - q)
        return self.plant_model.gravity(q)

    def _termination_reason(self) -> str | None:
        sim = self.sim
        speed = max(np.abs(sim.dq).max(), np.abs(sim.dtheta).max())
        if not np.isfinite(speed + sim.q.sum() + sim.theta.sum()):
            return "non-finite state"
        if speed > self.max_velocity:
            return "velocity limit exceeded"
        if self._limited and (np.any(sim.q < self.joint_lower) or np.any(sim.q > self.joint_upper)):
            return "joint limit exceeded"
        return None

    def _observe(self, ddq: np.ndarray, reference: np.ndarray) -> dict[str, np.ndarray]:
        sim, rng = self.sim, self.np_random
        if self.robot.elastic:
            obs = {"motor_position": self.encoder.measure(sim.theta, rng)}
        else:
            obs = {"link_position": self.encoder.measure(sim.q, rng)}
        if self.model.n_sensors:
            force = self.plant_model.accelerometer_readings(sim.q, sim.dq, ddq)
            obs["acceleration"] = self.accelerometer_array.measure(force, rng)
        self._sensor_queue.append(obs)
        while len(self._sensor_queue) <= self.sensor_delay:  # at reset: the first reading
            self._sensor_queue.appendleft(obs)
        obs = {key: value.copy() for key, value in self._sensor_queue[0].items()}
        obs["reference"] = np.concatenate([reference[0], reference[1]])
        self._last_obs = obs
        return obs

    def _reward(self, tau: np.ndarray, previous: np.ndarray, reference: np.ndarray) -> float:
        sim = self.sim
        arm = (sim.q - reference[0], sim.dq - reference[1], tau, previous, self.torque_limit,
               sim.theta - sim.q)
        return float(total_reward(self.reward_config, self.control_dt, *(a[None] for a in arm))[0])

    def _info(
        self, ddq: np.ndarray, tau: np.ndarray, saturated: bool, reference: np.ndarray
    ) -> dict:
        sim = self.sim
        return {
            "time": self.time,
            "true_state": {
                "q": sim.q.copy(),
                "dq": sim.dq.copy(),
                "theta": sim.theta.copy(),
                "dtheta": sim.dtheta.copy(),
                "ddq": ddq,
                "x": sim.state,
            },
            "torque": tau.copy(),
            "torque_saturated": saturated,
            "reference": {
                "q": reference[0], "dq": reference[1], "ddq": reference[2],
                "d3q": reference[3], "d4q": reference[4],
            },
            "termination_reason": None,
        }


class ElasticArmEnv(ArmEnv):
    """Arm with elastic joints: model (1), or model (2) when the robot has a coupling S."""

    def __init__(self, robot: str | RobotSpec = "two_link_elastic", **kwargs) -> None:
        super().__init__(robot, **kwargs)
        if not self.robot.elastic:
            raise ValueError(f"robot {self.robot.name!r} has rigid joints; use RigidArmEnv")


class RigidArmEnv(ArmEnv):
    """Arm with rigid joints measured by link encoders (the rigid-robot observer papers)."""

    def __init__(self, robot: str | RobotSpec = "two_link_rigid", **kwargs) -> None:
        super().__init__(robot, **kwargs)
        if self.robot.elastic:
            raise ValueError(f"robot {self.robot.name!r} has elastic joints; use ElasticArmEnv")
