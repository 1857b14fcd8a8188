"""Env kwargs of :class:`~elastic_gym.envs.batch.ArmBatch` as pydantic models.

:class:`EnvConfig` holds every kwarg of the batch (and so of every single and vector env);
unknown keys are refused and every error names its field path
(``per_arm[1].payload.mass: ...``). What pydantic cannot know — a robot's joint count,
its torque limits, which parts it has — is checked where the robot is known
(:mod:`~elastic_gym.envs.arm_config`). Plant features no model knows:
``actuator_delay`` (the torque acts k control periods late), ``torque_pulses`` (link-side
pulses, given or drawn at every reset from the arm's plant stream; a pulse acts on the
control periods that start in [time, time + duration)) and ``payload`` (a point mass at
the last actuated link, optionally changing at a given time). ``per_arm``: N mappings of
the per-arm kwargs (:data:`PER_ARM_KEYS`), each deep-merged into the shared kwargs for its
arm. ``randomize``: parameter path -> :class:`Range`, drawn at every reset.
"""

from __future__ import annotations

import math
from typing import Annotated, Any

from pydantic import (
    BeforeValidator,
    Field,
    StrictFloat,
    StrictInt,
    field_validator,
    model_validator,
)

from elastic_gym.envs.sensors import AccelerometerConfig, EncoderConfig
from elastic_gym.validation import StrictModel

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


def _ideal_accelerometer(value: Any) -> Any:
    """``"ideal"`` is :meth:`AccelerometerConfig.ideal`; no other string is an error model."""
    if isinstance(value, str):
        if value != "ideal":
            raise ValueError(
                "must be 'ideal', a mapping of AccelerometerConfig fields or None, "
                f"got the string {value!r}"
            )
        return AccelerometerConfig.ideal()
    return value


Accelerometer = Annotated[AccelerometerConfig | None, BeforeValidator(_ideal_accelerometer)]
PositiveNumber = Annotated[StrictFloat, Field(gt=0.0, allow_inf_nan=False)]
Periods = Annotated[StrictInt, Field(ge=0)]  # a count of control periods


def _finite(value: float) -> float:
    if not math.isfinite(value):
        raise ValueError(f"must be finite, got {value!r}")
    return value


class Range(StrictModel):
    """A range ``[low, high]`` drawn uniformly, or log-uniformly (``log: true``: log x is
    uniform in [log low, log high], low > 0). Integer parameters draw an integer uniformly
    in {low, ..., high}."""

    low: float
    high: float
    log: bool = False

    _finite_ends = field_validator("low", "high")(_finite)

    @model_validator(mode="after")
    def _ordered(self) -> Range:
        if self.low > self.high:
            raise ValueError(f"low ({self.low}) must be <= high ({self.high})")
        if self.log and self.low <= 0.0:
            raise ValueError(f"a log-uniform range needs low > 0, got {self.low}")
        return self


class PayloadChange(StrictModel):
    time: float = Field(gt=0.0)
    mass: float = Field(ge=0.0, le=MAX_PAYLOAD)

    _finite_time = field_validator("time")(_finite)


class PayloadConfig(StrictModel):
    mass: float = Field(ge=0.0, le=MAX_PAYLOAD)
    position: tuple[float, float, float] | None = None
    change: PayloadChange | None = None

    @field_validator("position")
    @classmethod
    def _finite_position(cls, value):
        if value is not None:
            for x in value:
                _finite(x)
        return value


class RandomPulses(StrictModel):
    count: int = Field(ge=1, le=MAX_PULSES)
    window: tuple[float, float]
    duration: Range
    amplitude: Range

    @model_validator(mode="after")
    def _bounds(self) -> RandomPulses:
        start, end = self.window
        if not (math.isfinite(start) and math.isfinite(end) and 0.0 <= start <= end):
            raise ValueError(f"window must be 0 <= start <= end (s), got {self.window}")
        if self.duration.low <= 0.0:
            raise ValueError(f"duration.low must be > 0 s, got {self.duration.low}")
        if self.amplitude.low < 0.0:
            raise ValueError(
                f"amplitude (fractions of the torque limit) must be >= 0, got {self.amplitude.low}"
            )
        return self


class TorquePulsesConfig(StrictModel):
    times: list[float] | None = None
    durations: list[float] | None = None
    amplitudes: list[float | list[float]] | None = None
    random: RandomPulses | None = None

    @model_validator(mode="after")
    def _one_form(self) -> TorquePulsesConfig:
        times, durations, amplitudes = self.times, self.durations, self.amplitudes
        if self.random is not None:
            if times is not None or durations is not None or amplitudes is not None:
                raise ValueError("give either times/durations/amplitudes or random, not both")
            return self
        if times is None or durations is None or amplitudes is None:
            raise ValueError("give times, durations and amplitudes (or random)")
        if not len(times) == len(durations) == len(amplitudes):
            raise ValueError("times, durations and amplitudes need one entry per pulse")
        if len(times) > MAX_PULSES:
            raise ValueError(f"at most {MAX_PULSES} pulses")
        if any(not (math.isfinite(t) and t >= 0.0) for t in times):
            raise ValueError(f"times must be finite and >= 0 s, got {times}")
        if any(not (math.isfinite(d) and d > 0.0) for d in durations):
            raise ValueError(f"durations must be finite and > 0 s, got {durations}")
        return self


class ArmOptions(StrictModel):
    """The per-arm kwargs of one arm (one entry of ``per_arm``); None keeps the shared one.

    The fields without a model here keep their own validators (the robot must be known)."""

    plant_scaling: Any = None
    unmodelled_friction: Any = None
    encoder: EncoderConfig | None = None
    accelerometer: Accelerometer = None
    sensor_delay: Periods | None = None
    actuator_delay: Periods | None = None
    payload: PayloadConfig | None = None
    torque_pulses: TorquePulsesConfig | None = None
    randomize: dict[str, Range] | None = None


class EnvConfig(StrictModel):
    """Every env kwarg of :class:`~elastic_gym.envs.batch.ArmBatch` (see its docstring).

    Typed here: what needs no robot. The plant scaling
    (:class:`~elastic_gym.model.ParameterScaling`) and the reward
    (:class:`~elastic_gym.envs.reward.RewardConfig`) keep their own config classes, the
    task options are checked by the task, the robot-dependent limits (joint counts, a
    delay longer than 1 s, friction in fractions of the torque limits, a physics step too
    coarse for the stiffest joint) by the batch."""

    task: str = "tracking"
    task_options: dict | None = None
    physics_dt: Annotated[PositiveNumber, Field(le=MAX_PHYSICS_DT)] | None = None
    control_dt: Annotated[PositiveNumber, Field(le=MAX_CONTROL_DT)] | None = None
    encoder: EncoderConfig | None = None
    accelerometer: Accelerometer = None
    accelerometers: list | None = None
    plant_scaling: Any = None
    unmodelled_friction: Any = None
    torque_limit: PositiveNumber | list[PositiveNumber] | None = None
    reward: Any = None
    max_velocity: PositiveNumber = 100.0
    sensor_delay: Periods = 0
    actuator_delay: Periods = 0
    payload: PayloadConfig | None = None
    torque_pulses: TorquePulsesConfig | None = None
    randomize: dict[str, Range] | None = None
    per_arm: list[ArmOptions] | None = None
    episode_time: PositiveNumber | None = EPISODE_TIME
