"""Env kwargs of [`ArmBatch`][elastic_gym.envs.batch.ArmBatch] as pydantic models.

`EnvConfig` holds every kwarg of the batch (and so of every single and vector env);
unknown keys are refused and every error names its field path
(``per_arm[1].payload.mass: ...``). What pydantic cannot know — a robot's joint count,
its torque limits, which parts it has — is checked where the robot is known
(`arm_config`). Plant features no model knows:
``actuator_delay`` (the torque acts k control periods late), ``torque_pulses`` (link-side
pulses, given or drawn at every reset from the arm's plant stream; a pulse acts on the
control periods that start in [time, time + duration)) and ``payload`` (a point mass at
the last actuated link, optionally changing at a given time). ``per_arm``: N mappings of
the per-arm kwargs (`PER_ARM_KEYS`), each deep-merged into the shared kwargs for its
arm. ``randomize``: parameter path -> [`PlantRange`][elastic_gym.envs.config.PlantRange], drawn at
every reset.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any, Literal

import pydantic_core
from pydantic import (
    AfterValidator,
    BeforeValidator,
    Field,
    StrictInt,
    WithJsonSchema,
    model_validator,
)

from elastic_gym.envs.reward import RewardConfig
from elastic_gym.envs.sensors import AccelerometerConfig, EncoderConfig
from elastic_gym.model import ParameterScaling
from elastic_gym.robots.spec import AccelerometerMount
from elastic_gym.validation import (
    Finite,
    FiniteNumbers,
    NonNegativeFinite,
    NonNegativeNumbers,
    PositiveFinite,
    PositiveNumbers,
    StrictModel,
    all_or_none,
    at_most_one,
    checked,
    numbers,
    ordered,
    plain,
)

PER_ARM_KEYS = (
    "plant_scaling",
    "unmodelled_friction",
    "encoder",
    "accelerometer",
    "sensor_delay",
    "actuator_delay",
    "payload",
    "torque_pulses",
    "randomize",
)
MAX_PAYLOAD = 1e3  # kg
MAX_PULSES = 1000
MAX_PHYSICS_DT = 1e-3 + 1e-15  # s
MAX_CONTROL_DT = 0.1  # s: slower "control" is not torque control of an arm
EPISODE_TIME = 3.0  # s
RenderMode = Literal["human", "rgb_array"]
Integrator = Literal["pybullet", "rk4"]  # see EnvConfig.integrator
INTEGRATORS: tuple[str, ...] = ("pybullet", "rk4")


def _ideal_accelerometer(value: Any) -> Any:
    """``"ideal"`` is
    [`AccelerometerConfig.ideal`][elastic_gym.envs.sensors.AccelerometerConfig.ideal]; no other
    string is an error model."""
    if isinstance(value, str):
        if value != "ideal":
            raise ValueError(
                "must be 'ideal', a mapping of AccelerometerConfig fields or None, "
                f"got the string {value!r}"
            )
        return AccelerometerConfig.ideal()
    return value


class _OrIdeal:
    """JSON Schema: the string ``"ideal"`` besides the annotated type's own."""

    @staticmethod
    def __get_pydantic_json_schema__(core_schema: Any, handler: Any) -> dict:
        return {"anyOf": [{"const": "ideal"}, handler(core_schema)]}


Accelerometer = Annotated[
    AccelerometerConfig | None, BeforeValidator(_ideal_accelerometer), _OrIdeal()
]
Periods = Annotated[StrictInt, Field(ge=0)]  # a count of control periods
Payload = Annotated[NonNegativeFinite, Field(le=MAX_PAYLOAD)]  # kg


class Range(StrictModel):
    """A range ``[low, high]`` drawn uniformly, or log-uniformly (``log: true``: log x is
    uniform in [log low, log high], low > 0). Integer parameters draw an integer uniformly
    in {low, ..., high}."""

    low: Finite
    high: Finite
    log: bool = False

    @model_validator(mode="after")
    def _ordered(self) -> Range:
        ordered(self.low, self.high)
        if self.log:
            numbers(
                self.low, "", "a log-uniform range needs low > 0", [()], minimum=0.0, strict=True
            )
        return self


class PlantRange(Range):
    """A ``randomize`` range: a reset draws from it with ``probability`` (default 1, every
    reset); at the other resets the path takes ``otherwise`` (default ``low``), e.g.
    ``{low: 1, high: 1, probability: 0.2, otherwise: 0}`` delays a fifth of the
    episodes."""

    probability: Annotated[Finite, Field(gt=0.0, le=1.0)] = 1.0
    otherwise: Finite | None = None

    @model_validator(mode="after")
    def _otherwise_used(self) -> PlantRange:
        if self.otherwise is not None and self.probability == 1.0:
            raise ValueError("otherwise is used only with a probability below 1")
        return self

    @property
    def fallback(self) -> float:
        """The value at the resets that do not draw."""
        return self.low if self.otherwise is None else self.otherwise

    @property
    def maximum(self) -> float:
        """The largest value the range gives."""
        return max(self.high, self.fallback)


class PositiveRange(Range):
    low: PositiveFinite


class NonNegativeRange(Range):
    low: NonNegativeFinite


class PayloadChange(StrictModel):
    time: PositiveFinite
    mass: Payload


class PayloadConfig(StrictModel):
    mass: Payload
    position: tuple[Finite, Finite, Finite] | None = None
    change: PayloadChange | None = None


class RandomPulses(StrictModel):
    count: int = Field(ge=1, le=MAX_PULSES)
    window: tuple[NonNegativeFinite, NonNegativeFinite]
    duration: PositiveRange  # s
    amplitude: NonNegativeRange  # fractions of the torque limit

    @model_validator(mode="after")
    def _bounds(self) -> RandomPulses:
        ordered(*self.window, names=("start", "end"), loc=("window",))
        return self


Pulses = Field(None, max_length=MAX_PULSES)


class TorquePulsesConfig(StrictModel):
    times: list[NonNegativeFinite] | None = Pulses  # s
    durations: list[PositiveFinite] | None = Pulses  # s
    amplitudes: list[FiniteNumbers] | None = Pulses
    random: RandomPulses | None = None

    @model_validator(mode="after")
    def _one_form(self) -> TorquePulsesConfig:
        all_or_none(
            {"times": self.times, "durations": self.durations, "amplitudes": self.amplitudes}
        )
        at_most_one({"times": self.times, "random": self.random}, required=True)
        if self.times is not None and not (
            len(self.times) == len(self.durations) == len(self.amplitudes)  # type: ignore[arg-type]
        ):
            raise ValueError("times, durations and amplitudes need one entry per pulse")
        return self


class UnmodelledFriction(StrictModel):
    """Link friction no model knows, in fractions of each joint's motor torque limit:
    ``coulomb`` below 1 (the motor could not move the joint otherwise), ``viscous`` at
    most 1 s/rad (scalars or per joint)."""

    coulomb: NonNegativeNumbers = 0.0
    viscous: NonNegativeNumbers = 0.0

    @model_validator(mode="after")
    def _movable(self) -> UnmodelledFriction:
        coulomb = self.coulomb if isinstance(self.coulomb, tuple) else (self.coulomb,)
        viscous = self.viscous if isinstance(self.viscous, tuple) else (self.viscous,)
        if max(coulomb) >= 1.0 or max(viscous) > 1.0:
            raise ValueError(
                "coulomb must stay below 1 (the motor could not move the joint) and viscous "
                f"at most 1 s/rad, got coulomb={self.coulomb}, viscous={self.viscous}"
            )
        return self


class ArmOptions(StrictModel):
    """The per-arm kwargs of one arm (one entry of ``per_arm``); None keeps the shared one.
    What needs the robot (joint counts, delays in seconds) is checked by
    `ArmResolver`."""

    plant_scaling: ParameterScaling | None = None
    unmodelled_friction: UnmodelledFriction | None = None
    encoder: EncoderConfig | None = None
    accelerometer: Accelerometer = None
    sensor_delay: Periods | None = None
    actuator_delay: Periods | None = None
    payload: PayloadConfig | None = None
    torque_pulses: TorquePulsesConfig | None = None
    randomize: dict[str, PlantRange] | None = None


class EnvConfig(StrictModel):
    """Every env kwarg: the options of an [`ArmBatch`][elastic_gym.envs.batch.ArmBatch],
    and so of every single and vector env of the package.

    Typed here: what needs no robot. The task options are checked by the task, the
    robot-dependent limits (a sensor on a link the robot lacks, joint counts, a
    delay longer than 1 s, friction in fractions of the torque limits, a physics step too
    coarse for the stiffest joint) by the batch
    ([`batch_setup`][elastic_gym.envs.batch_setup]).

    Attributes:
        task: `"tracking"`, `"regulation"` or `"excitation"`.
        task_options: options of the task (see [`tasks`][elastic_gym.envs.tasks]).
        integrator: `"pybullet"` (PyBullet's first-order semi-implicit Euler at
            `physics_dt`, the elastic transmission beside each step) or `"rk4"` (the
            compiled 4th-order Runge-Kutta of the whole state over each control period,
            with step-size control per arm; PyBullet stays the world: rendering, GUI,
            link poses), see [`integration`][elastic_gym.envs.integration].
        physics_dt: physics step (s), default from the robot; with `"pybullet"` it must
            keep `physics_dt * omega_max <= 0.2` for the stiffest joint mode; with
            `"rk4"` the largest substep (default: the control period).
        control_dt: control period (s), an integer multiple of `physics_dt` (default from
            the robot, 1 ms).
        encoder: `{"resolution": rad, "noise_std": rad}`.
        accelerometer: error model, see `AccelerometerConfig` (`"ideal"` for none).
        accelerometers: list of mounts `{"link", "position", "rpy", "name"}` replacing
            the robot's default sensor placement.
        plant_scaling: parameter changes of the *simulated* robot relative to the nominal
            model (`ParameterScaling` fields, e.g. `{"link_mass": 1.3}`).
        unmodelled_friction: link-side joint friction of the *simulated* robot that no
            model knows, `{"coulomb": c, "viscous": v}` (scalars or per joint) in
            fractions of each joint's motor torque limit:
            d(q') = tau_max (v q' + c tanh(q' / 0.01 rad/s)), added to the robot's own.
        torque_limit: override of the motor torque limits (N m).
        reward: weights and scales of the reward, see
            [`RewardConfig`][elastic_gym.envs.reward.RewardConfig] (also the termination
            reward).
        max_velocity: |q'| or |theta'| above this ends the episode (rad/s).
        sensor_delay: measurement delay in control periods (encoders and accelerometers;
            the reference is not delayed).
        actuator_delay: the motor torque is applied this many control periods late.
        payload: a point mass at the end effector, `{"mass", "position", "change":
            {"time", "mass"}}` (see the module docstring).
        torque_pulses: link-side torque pulses, given or random (see the module docstring
            and `envs.disturbances`).
        randomize: parameter path -> range drawn by each arm at every reset (see
            [`randomization`][elastic_gym.envs.randomization]).
        per_arm: None or N mappings of the per-arm kwargs (`PER_ARM_KEYS`): arm i's
            kwargs are the shared ones deep-merged with mapping i (the fields it gives),
            and arm i is bit for bit the single env made with them.
        episode_time: simulated seconds after which an episode is truncated (None: never).
    """

    task: str = "tracking"
    task_options: dict | None = None
    integrator: Integrator = "pybullet"
    physics_dt: Annotated[PositiveFinite, Field(le=MAX_PHYSICS_DT)] | None = None
    control_dt: Annotated[PositiveFinite, Field(le=MAX_CONTROL_DT)] | None = None
    encoder: EncoderConfig | None = None
    accelerometer: Accelerometer = None
    accelerometers: list[AccelerometerMount] | None = None
    plant_scaling: ParameterScaling | None = None
    unmodelled_friction: UnmodelledFriction | None = None
    torque_limit: PositiveNumbers | None = None
    reward: RewardConfig | None = None
    max_velocity: PositiveFinite = 100.0
    sensor_delay: Periods = 0
    actuator_delay: Periods = 0
    payload: PayloadConfig | None = None
    torque_pulses: TorquePulsesConfig | None = None
    randomize: dict[str, PlantRange] | None = None
    per_arm: list[ArmOptions] | None = None
    episode_time: PositiveFinite | None = EPISODE_TIME


class EnvKwargs(EnvConfig):
    """The keyword arguments of an env of the package (``gym.make(id, **kwargs)``): the
    batch's (`EnvConfig`) and the env's own ``robot`` (a name of the catalog,
    default the id's) and ``render_mode``. Scenarios and training configs validate their
    env kwargs with it."""

    robot: Annotated[Any, WithJsonSchema({"type": "string"})] = None
    render_mode: RenderMode | None = None


class MakeKwargs(EnvKwargs):
    """The keyword arguments of ``gym.make`` / ``gym.make_vec`` for an env of the package
    (what a training run passes): [`EnvKwargs`][elastic_gym.envs.config.EnvKwargs] and
    ``max_episode_steps`` (a
    ``TimeLimit`` in control periods)."""

    max_episode_steps: Annotated[StrictInt, Field(ge=1)] | None = None


def checked_kwargs(kwargs: dict, loc: tuple = (), model: type[EnvKwargs] = EnvKwargs) -> dict:
    """``kwargs`` (all or some of an env's) validated by ``model`` and returned as given;
    `ConfigError` with the field path
    (``plant_scaling.link_mass: ...``) after ``loc`` otherwise."""
    checked(lambda: model.model_validate(plain(kwargs)), "", model, loc=loc)
    return kwargs


@dataclass(frozen=True)
class KwargsSchema:
    """JSON Schema of a mapping of env kwargs: ``model``'s."""

    model: type[EnvKwargs] = EnvKwargs

    def __get_pydantic_json_schema__(self, core_schema: Any, handler: Any) -> dict:
        schema = self.model.__pydantic_core_schema__
        if schema["type"] == "model":  # a definition of its own (``$ref``), as a field's model
            reference = pydantic_core.core_schema.definition_reference_schema(schema["ref"])
            schema = pydantic_core.core_schema.definitions_schema(reference, [schema])
        return handler(schema)


# the kwargs of gym.make for a package env as a plain mapping (as given), validated
MakeKwargsMapping = Annotated[
    dict[str, Any],
    AfterValidator(lambda kwargs: checked_kwargs(kwargs, model=MakeKwargs)),
    KwargsSchema(MakeKwargs),
]


# ------------------------------------------------------------------------ reset options
MAX_ANGLE = 1e3  # rad: a larger initial angle has lost its precision
Angles = tuple[Annotated[Finite, Field(ge=-MAX_ANGLE, le=MAX_ANGLE)], ...]


class RigidInitialState(StrictModel):
    """``initial_state`` of a rigid arm: link angles (rad) and velocities (rad/s), one per
    joint (their count, ``max_velocity`` and the joint limits are checked by the batch)."""

    q: Angles | None = None
    dq: tuple[Finite, ...] | None = None


class ElasticInitialState(RigidInitialState):
    """``initial_state`` of an elastic arm: also the motor angles and velocities."""

    theta: Angles | None = None
    dtheta: tuple[Finite, ...] | None = None


class RigidResetOptions(StrictModel):
    """The ``options`` of a rigid arm's ``reset``."""

    initial_state: RigidInitialState | None = None


class ElasticResetOptions(StrictModel):
    """The ``options`` of an elastic arm's ``reset``."""

    initial_state: ElasticInitialState | None = None
