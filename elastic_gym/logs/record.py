"""Logs recorded from the envs: a closed loop (a controller on a state source, the env's
task) with a [`LogRecorder`][elastic_gym.logs.recorder.LogRecorder] under the observer
wrapper, and the identification excitation (`elastic_gym.logs.excitation`) tracked that
way. `record_excitation` is the Python face of `elastic-gym record`: the plant may differ
from the nominal model (`plant_scaling`, `unmodelled_friction` of the env kwargs: a
"mystery arm"), whose kwargs the log's provenance keeps for studies.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

import elastic_gym
from elastic_gym.arms import elastic_base
from elastic_gym.controllers.base import Controller, public_info
from elastic_gym.controllers.registry import make_controller
from elastic_gym.envs.fourier import DitherOptions, FourierTask
from elastic_gym.envs.ids import registered_env_id
from elastic_gym.logs.excitation import ExcitationDesign, design_excitation
from elastic_gym.logs.recorder import LogRecorder
from elastic_gym.logs.sensor_log import SensorLog
from elastic_gym.model import RobotModel
from elastic_gym.observers.wrappers import ObserverWrapper
from elastic_gym.robots.catalog import get_robot
from elastic_gym.robots.spec import AccelerometerMount, RobotSpec
from elastic_gym.validation import per_joint_values

DEFAULT_CONTROLLER = "motor-pd"  # on a rigid arm: RIGID_CONTROLLER
RIGID_CONTROLLER = "link-pd"
DEFAULT_CONTROLLER_OPTIONS: dict[str, Any] = {"omega": 20.0}
DEFAULT_SOURCE = "true"


@dataclass(frozen=True)
class Excitation:
    """The identification excitation's settings: the reference's `period` (s),
    `harmonics`, `fill` (of the workspace box's half-width), `torque_fill` (of the torque
    limits, for the rigid torque along the reference), `ramp` (s), the `dither` (None:
    none) and the design's `evaluations`."""

    period: float = 10.0
    harmonics: int = 5
    fill: float = 0.6
    torque_fill: float = 0.5
    ramp: float = 1.0
    dither: DitherOptions | None = field(default_factory=DitherOptions)
    evaluations: int = 400


def robot_and_limits(env_id: str, env_kwargs: Mapping) -> tuple[RobotSpec, RobotModel, np.ndarray]:
    """The robot of an env id with its kwargs: spec, nominal model, torque limits."""
    registered = gym.registry[registered_env_id(env_id)].kwargs.get("robot")
    robot = env_kwargs.get("robot", registered)
    spec = robot if isinstance(robot, RobotSpec) else get_robot(robot)
    mounts = env_kwargs.get("accelerometers")
    model = RobotModel(
        spec,
        accelerometers=None
        if mounts is None
        else tuple(AccelerometerMount.from_config(m) for m in mounts),
    )
    limit = env_kwargs.get("torque_limit", spec.torque_limit)
    return spec, model, per_joint_values(limit, spec.n_joints, "torque_limit", 0.0, strict=True)


def design_for(
    spec: RobotSpec, model: RobotModel, limit: np.ndarray, excitation: Excitation, seed: int
) -> ExcitationDesign:
    """The excitation designed on the nominal model (the plant is unknown)."""
    dither = None
    if excitation.dither is not None:
        dither = excitation.dither.model_copy(update={"seed": seed})
    return design_excitation(
        model,
        limit,
        np.asarray(spec.workspace_low, dtype=float),
        np.asarray(spec.workspace_high, dtype=float),
        period=excitation.period,
        harmonics=excitation.harmonics,
        fill=excitation.fill,
        torque_fill=excitation.torque_fill,
        dither=dither,
        seed=seed,
        evaluations=excitation.evaluations,
        ramp=excitation.ramp,
    )


def run_closed_loop(
    env_id: str,
    env_kwargs: Mapping[str, Any],
    duration: float,
    seed: int,
    controller: str | type[Controller] = DEFAULT_CONTROLLER,
    controller_options: Mapping[str, Any] | None = None,
    state_source: str = DEFAULT_SOURCE,
    source_options: Mapping[str, Any] | None = None,
    provenance: Mapping[str, Any] | None = None,
    reset_options: Mapping[str, Any] | None = None,
) -> SensorLog:
    """Run `controller` on `state_source` in the env for `duration` seconds and return
    what the sensors gave as a log (the truth in the state columns). A run the env ends
    early (a joint limit, a non-finite state or estimate) is a `RuntimeError`."""
    kwargs = {**dict(env_kwargs), "episode_time": duration}
    env = gym.make(registered_env_id(env_id), **kwargs)
    try:
        recorder = LogRecorder(env)
        base = elastic_base(env, "record", vector=False)
        options = dict(controller_options or {})
        law = (
            make_controller(controller, base.model, base.control_dt, **options)
            if isinstance(controller, str)
            else controller(base.model, base.control_dt, **options)
        )
        wrapped = ObserverWrapper(recorder, state_source, **dict(source_options or {}))
        obs, info = wrapped.reset(seed=seed, options=dict(reset_options or {}) or None)
        law.reset(obs, public_info(info))
        while True:
            obs, _, terminated, truncated, info = wrapped.step(law(obs, public_info(info)))
            if terminated:
                raise RuntimeError(
                    f"the run ended at t = {info['time']:.3f} s: "
                    f"{info.get('termination_reason')} "
                    f"{info.get('observer_error') or ''}".rstrip()
                )
            if truncated:
                break
        name = controller if isinstance(controller, str) else controller.__name__
        record = {
            "writer": "elastic_gym.logs.record",
            "version": elastic_gym.__version__,
            "seed": seed,
            "controller": {"name": name, "options": options, "state_source": state_source},
            **dict(provenance or {}),
        }
        return recorder.log(record)
    finally:
        env.close()


def record_excitation(
    env_id: str,
    duration: float = 60.0,
    seed: int = 0,
    env_kwargs: Mapping[str, Any] | None = None,
    excitation: Excitation | None = None,
    controller: str | type[Controller] | None = None,
    controller_options: Mapping[str, Any] | None = None,
    state_source: str = DEFAULT_SOURCE,
) -> tuple[SensorLog, ExcitationDesign]:
    """A log of the identification excitation (module docstring): the `fourier` task with
    coefficients designed for the nominal model and a dither, tracked by `controller`
    (default a motor PD at 20 rad/s with the INVDYN feedforward, on the true state; a link
    PD on a rigid arm)."""
    kwargs = dict(env_kwargs or {})
    if "task" in kwargs or "task_options" in kwargs:
        raise ValueError("the excitation sets the task: leave task and task_options out")
    excitation = excitation or Excitation()
    spec, model, limit = robot_and_limits(env_id, kwargs)
    design = design_for(spec, model, limit, excitation, seed)
    if controller is None:
        controller = DEFAULT_CONTROLLER if spec.elastic else RIGID_CONTROLLER
    options = DEFAULT_CONTROLLER_OPTIONS if controller_options is None else controller_options
    log = run_closed_loop(
        env_id,
        {**kwargs, "task": "fourier", "task_options": design.task_options},
        duration,
        seed,
        controller,
        options,
        state_source,
        provenance={
            "excitation": {  # the coefficients are the task_options of env_kwargs
                "design": "elastic_gym.logs.excitation.design_excitation",
                "condition_number": design.condition_number,
                "base_columns": design.base_columns,
                "torque_ratio": design.torque_ratio,
            }
        },
    )
    return log, design


REFERENCE_BLOCKS = ("q_d", "dq_d", "ddq_d", "d3q_d", "d4q_d")


def reference_table(
    spec: RobotSpec, task_options: Mapping[str, Any], duration: float, sample_time: float
) -> tuple[list[str], np.ndarray]:
    """The excitation as a table a real robot can follow: `time`, the reference q_d and
    its four derivatives (`q_d_<j>`, `dq_d_<j>`, `ddq_d_<j>`, `d3q_d_<j>`, `d4q_d_<j>`)
    and the dither torque to add to the controller's (`dither_<j>`, N m), per sample."""
    from elastic_gym.envs.tasks import make_task

    model = RobotModel(spec)
    task = make_task("fourier", spec, model, dict(task_options))
    assert isinstance(task, FourierTask)
    time = np.arange(round(duration / sample_time)) * sample_time
    reference = task.reference_at(time)
    n = spec.n_joints
    header = ["time"] + [f"{block}_{j}" for block in REFERENCE_BLOCKS for j in range(1, n + 1)]
    header += [f"dither_{j}" for j in range(1, n + 1)]
    values = np.hstack([time[:, None], reference.reshape(len(time), -1), task.dither_at(time)])
    return header, values
