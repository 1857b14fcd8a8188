"""Gymnasium environments of one arm with elastic (or rigid) joints and realistic sensing.

`ArmEnv` is the N = 1 case of [`ArmBatch`][elastic_gym.envs.batch.ArmBatch], whose
module docstring documents the observation, the info, the reward and the termination.
No link position and no velocity of an elastic arm is ever observed; the ground truth
is in ``info["true_state"]``. Action: motor torque (N m), clipped to the torque limits
(``info["torque_saturated"]``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from numba import njit

from elastic_gym.envs.batch import ArmBatch
from elastic_gym.envs.config import RenderMode
from elastic_gym.envs.signature import with_batch_options
from elastic_gym.model.packed import direct
from elastic_gym.robots.spec import RobotSpec
from elastic_gym.validation import option_value

ARM = np.array([0])
FLOAT64 = np.dtype(np.float64)


def validated_actions(action, n_arms: int, n_joints: int) -> np.ndarray:
    """Actions as float64 of shape (n_arms, n_joints) (a single arm: shape (n_joints,)).

    Raises ``TypeError`` for a non-numeric dtype and ``ValueError`` for a wrong shape or a
    non-finite entry, before anything is changed.
    """
    arr = np.asarray(action)
    if arr.dtype.kind not in "fiu":
        raise TypeError(f"action must be a real numeric array, got dtype {arr.dtype}")
    shape = (n_joints,) if n_arms == 0 else (n_arms, n_joints)
    if arr.shape != shape:
        raise ValueError(f"action must have shape {shape}, got {arr.shape}")
    arr = arr.astype(np.float64).reshape(-1, n_joints)
    if not _all_finite(arr):
        raise ValueError(f"action must be finite, got {arr.reshape(shape)}")
    return arr


def _arm_action(action, n_joints: int) -> np.ndarray:
    """`validated_actions` of a single arm, (1, n_joints): a C-contiguous, writeable
    float64 array of shape (n_joints,), what a policy or `action_space.sample()` gives,
    is checked in place and given as a view (a step reads it and keeps nothing of it);
    anything else is converted and checked by `validated_actions`, with its errors."""
    if type(action) is np.ndarray and action.dtype is FLOAT64 and action.shape == (n_joints,):
        flags = action.flags
        if flags.c_contiguous and flags.writeable:
            arr = action.reshape(1, n_joints)
            if _finite_row()(arr):
                return arr
    return validated_actions(action, 0, n_joints)


@functools.cache
def _finite_row() -> Callable[[np.ndarray], bool]:
    """`_all_finite` of C-contiguous float64 2-D arrays through its entry point (`direct`:
    without numba's dispatch), found at the first call."""
    return direct(_all_finite, np.zeros((1, 1)))


@njit(cache=True)
def _all_finite(values):
    """Whether every entry of ``values`` (2-D) is finite (one compiled loop: a numpy
    reduction costs more than the whole test for the few numbers of an action)."""
    for k in range(values.shape[0]):
        for j in range(values.shape[1]):
            if not np.isfinite(values[k, j]):
                return False
    return True


def _from_batch(name: str, doc: str) -> property:
    return property(lambda self: getattr(self.batch, name), doc=doc)


def check_kind(batch: ArmBatch, kind: str | None, suffix: str = "Env") -> None:
    """Refuse (closing ``batch``) a robot whose joints are not of an env class's ``kind``
    (``"elastic"``, ``"rigid"``; ``None``: any), naming the class to use instead
    (``RigidArm<suffix>``)."""
    spec = batch.robot
    if kind is not None and spec.kind != kind:
        batch.close()
        other = "ElasticArm" if spec.elastic else "RigidArm"
        raise ValueError(f"robot {spec.name!r} has {spec.kind} joints; use {other}{suffix}")


class ArmEnv(gym.Env):
    """An arm of the catalog in PyBullet with sensors, a task and a nominal model.

    Args:
        robot: robot name (``elastic_gym.robots.catalog.ROBOTS``) or a ``RobotSpec``.
        render_mode: ``"rgb_array"`` or ``"human"``.
        **kwargs: the options of [`ArmBatch`][elastic_gym.envs.batch.ArmBatch] (task,
            task_options, physics_dt, control_dt, encoder, accelerometer, accelerometers,
            plant_scaling, unmodelled_friction, torque_limit, reward, max_velocity,
            sensor_delay, actuator_delay, payload, torque_pulses, randomize, per_arm,
            episode_time).

    Attributes: ``model`` (the nominal [`RobotModel`][elastic_gym.model.RobotModel] for
    observers and controllers), ``plant_model`` (the simulated plant's), ``robot``,
    ``torque_limit``, ``control_dt``, ``physics_dt``, ``task``.
    """

    # replaced per instance in __init__ (gymnasium declares Env.metadata per instance)
    metadata: dict[str, Any] = {  # noqa: RUF012
        "render_modes": ["human", "rgb_array"],
        "render_fps": 30,
    }
    kind: ClassVar[str | None] = None  # "elastic" / "rigid" for the subclasses

    @with_batch_options
    def __init__(self, robot: str | RobotSpec, render_mode: str | None = None, **kwargs) -> None:
        option_value("render_mode", render_mode, RenderMode | None, prefix="")
        self._init_kwargs = {"robot": robot, "render_mode": render_mode, **kwargs}
        self.render_mode = render_mode
        self.batch = ArmBatch(robot, 1, kwargs, gui=render_mode == "human")
        check_kind(self.batch, self.kind)
        self._set_spaces()

    robot = _from_batch("robot", "The RobotSpec.")
    model = _from_batch("model", "Nominal RobotModel (what observers and controllers use).")
    plant_model = _from_batch("plant_model", "RobotModel of the simulated plant.")
    task = _from_batch("task", "The task (reference, external torque).")
    torque_limit = _from_batch("torque_limit", "Motor torque limits (N m).")
    control_dt = _from_batch("control_dt", "Control period (s).")
    physics_dt = _from_batch("physics_dt", "Physics step (s).")
    n_substeps = _from_batch("n_substeps", "Physics steps per control period.")
    n_joints = _from_batch("n_joints", "Number of joints.")
    encoder = _from_batch("encoder", "The position encoders.")
    accelerometer_array = _from_batch("accelerometer_array", "The accelerometers.")
    episode_time = _from_batch("episode_time", "Episode length (s) or None.")
    sim = _from_batch("sim", "The PyBullet simulator (one arm).")

    def _set_spaces(self) -> None:
        batch = self.batch
        self.metadata = {
            **self.metadata,
            # one frame per control period plays in real time
            "render_fps": round(1.0 / self.control_dt),
            "physics_dt": self.physics_dt,
            "control_dt": self.control_dt,
            "robot": self.robot.name,
            "task": self.task.name,
        }
        self.action_space = batch.single_action_space
        self.observation_space = batch.single_observation_space

    # ------------------------------------------------------------------ API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode at rest (or at ``options["initial_state"]``, see ArmBatch)."""
        batch = self.batch
        batch.check_open()
        own = self._np_random, self._np_random_seed
        try:
            with batch.generators_kept_on_error(ARM):  # a refused reset: no change
                super().reset(seed=seed)
                batch.set_generator(0, self.np_random)
                batch.reset_arms(ARM, options)
        except BaseException:  # nor of the env's own generator and seed
            self._np_random, self._np_random_seed = own
            raise
        return batch.arm_outputs(0)

    def step(self, action):
        batch = self.batch
        batch.check_open()
        tau = _arm_action(action, batch.n_joints)
        if not batch.episode.running[0]:
            raise RuntimeError("call reset() before step() (and after an episode has ended)")
        reward, terminated, truncated = batch.step(tau)
        obs, info = batch.arm_outputs(0)
        if self.render_mode == "human":
            self.render()
        return obs, reward.item(0), terminated.item(0), truncated.item(0), info

    @property
    def time(self) -> float:
        """Simulated time of the episode (s)."""
        return float(self.batch.time[0])

    def reference_preview(self, offsets) -> np.ndarray:
        """q_d .. q_d^(4) at the current time + each offset (s): (H, 5, n)."""
        return self.batch.reference_preview(offsets)[0]

    def render(self):
        if self.render_mode == "rgb_array":
            return self.batch.render(0)
        self.batch.check_open()
        return None

    def close(self) -> None:
        if getattr(self, "batch", None) is not None:
            self.batch.close()

    # ------------------------------------------------------------------ pickling
    def __getstate__(self) -> dict:
        """The batch pickles its constructor arguments and arm state (a PyBullet client
        cannot be pickled): a copy is an independent env that continues bit for bit."""
        return {
            "batch": self.batch,
            "render_mode": self.render_mode,
            "init": self._init_kwargs,
            "spec": getattr(self, "spec", None),
            "seeded": self._np_random is not None,
            "seed": self._np_random_seed,
        }

    def __setstate__(self, state: dict) -> None:
        self.batch = state["batch"]
        self.render_mode = state["render_mode"]
        self._init_kwargs = state["init"]
        self.spec = state["spec"]
        self._set_spaces()
        if state["seeded"]:
            self._np_random = self.batch.rngs[0]
            self._np_random_seed = state["seed"]


class ElasticArmEnv(ArmEnv):
    """Arm with elastic joints: model (1), or model (2) when the robot has a coupling S."""

    kind = "elastic"

    def __init__(self, robot: str | RobotSpec = "two_link_elastic", **kwargs) -> None:
        super().__init__(robot, **kwargs)


class RigidArmEnv(ArmEnv):
    """Arm with rigid joints measured by link encoders (the rigid-robot observer papers)."""

    kind = "rigid"

    def __init__(self, robot: str | RobotSpec = "two_link_rigid", **kwargs) -> None:
        super().__init__(robot, **kwargs)
