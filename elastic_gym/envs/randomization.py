"""Domain randomization: each arm draws its plant at every reset (the ``randomize`` kwarg).

``randomize`` maps a parameter path to a [`PlantRange`][elastic_gym.envs.config.PlantRange],
e.g. ``{"plant_scaling.link_mass": {"low": 0.7, "high": 1.3}, "sensor_delay": {"low": 0,
"high": 2}}``. At every reset each arm draws, from its own plant stream, one value per path
in the order of `PATHS`: uniform in [low, high], log-uniform (``log: true``:
exp(U(log low, log high))) or, for the integer paths, an integer uniform in
{low, ..., high}. A range with ``probability`` p < 1 first draws u ~ U[0, 1): the value
is drawn as above when u < p, else it is the range's ``otherwise`` (default ``low``).
The value replaces the arm's own setting of that path (a scalar: every joint gets it).
The plant stream of an arm is a generator seeded from its reset seed's ``SeedSequence``
with its own spawn key, apart from the task and sensor stream: turning randomization on
changes no task draw, and the same seed gives the same draws.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping

import numpy as np

from elastic_gym.envs.arm_config import ArmResolver, ArmSettings, deep_merge
from elastic_gym.envs.config import PlantRange
from elastic_gym.validation import errors_at, lookup

PLANT_STREAM = 0x706C616E  # spawn key of the plant stream ("plan")
# path -> integer-valued
PATHS: dict[str, bool] = {
    "plant_scaling.link_mass": False,
    "plant_scaling.link_inertia": False,
    "plant_scaling.stiffness": False,
    "plant_scaling.motor_inertia": False,
    "plant_scaling.damping": False,
    "plant_scaling.friction": False,
    "unmodelled_friction.coulomb": False,
    "unmodelled_friction.viscous": False,
    "encoder.resolution": False,
    "encoder.noise_std": False,
    "accelerometer.noise_density": False,
    "accelerometer.bias_std": False,
    "sensor_delay": True,
    "actuator_delay": True,
    "payload.mass": False,
}
# paths that change the plant's vibration frequencies (checked for stability at their ends)
MODE_PATHS = (
    "plant_scaling.link_mass",
    "plant_scaling.link_inertia",
    "plant_scaling.stiffness",
    "plant_scaling.motor_inertia",
    "payload.mass",
)


def plant_stream(rng: np.random.Generator) -> np.random.Generator:
    """The plant stream derived from an arm's task/sensor generator without drawing from it:
    same seed, same stream."""
    seq = rng.bit_generator.seed_seq
    if not isinstance(seq, np.random.SeedSequence):
        raise TypeError(f"an arm's generator needs a SeedSequence, got {type(seq).__name__}")
    child = np.random.SeedSequence(seq.entropy, spawn_key=(*seq.spawn_key, PLANT_STREAM))
    return np.random.default_rng(child)


def with_values(kwargs: Mapping, values: Mapping[str, float | int]) -> dict:
    """``kwargs`` with each path of ``values`` set to its value."""
    out = dict(kwargs)
    for path, value in values.items():
        key, _, field = path.partition(".")
        if not field:
            out[key] = value
            continue
        base = out.get(key)
        out[key] = deep_merge({} if base is None else base, {field: value})
    return out


def draw(ranges: Mapping[str, PlantRange], rng: np.random.Generator) -> dict[str, float | int]:
    """One value per path of ``ranges``, in the order of `PATHS`."""
    values: dict[str, float | int] = {}
    for path, integer in PATHS.items():
        spec = ranges.get(path)
        if spec is None:
            continue
        if spec.probability < 1.0 and rng.random() >= spec.probability:
            values[path] = int(spec.fallback) if integer else float(spec.fallback)
        elif integer:
            values[path] = int(rng.integers(int(spec.low), int(spec.high) + 1))
        elif spec.log:
            values[path] = float(np.exp(rng.uniform(np.log(spec.low), np.log(spec.high))))
        else:
            values[path] = float(rng.uniform(spec.low, spec.high))
    return values


def _ends(spec: PlantRange) -> dict[str, float]:
    """The values a range can give at its extremes: low, high and, drawn at a share of
    the resets, ``otherwise``."""
    ends = {"low": spec.low, "high": spec.high}
    if spec.otherwise is not None:
        ends["otherwise"] = spec.otherwise
    return ends


def check_ranges(
    ranges: Mapping[str, PlantRange], kwargs: Mapping, resolver: ArmResolver, prefix: str = ""
) -> list[ArmSettings]:
    """Refuse unknown paths, non-integer ends of integer paths and ends outside a
    parameter's admissible range; returns the settings of the corners of the
    frequency-changing paths (whose stability the caller checks)."""
    where = f"{prefix}randomize"
    for path, spec in ranges.items():
        with errors_at(where):
            integer = lookup(PATHS, path, "parameter path")
        ends = _ends(spec)
        if integer and any(value != int(value) for value in ends.values()):
            raise ValueError(f"{where}[{path!r}]: {path} takes integers, got {spec}")
        for end, value in ends.items():
            with errors_at(f"{where}[{path!r}].{end}"):
                resolver.settings(with_values(kwargs, {path: int(value) if integer else value}))
    modes = [p for p in MODE_PATHS if p in ranges]
    corners = itertools.product(*[tuple(_ends(ranges[p]).values()) for p in modes])
    return [
        resolver.settings(with_values(kwargs, dict(zip(modes, c, strict=True)))) for c in corners
    ]
