"""Comparison scenarios: the grid of runs, from a dict, a YAML file or a shipped preset.

A scenario is the product

    envs x (values of each robustness axis) x model errors x seeds x controllers x state sources

written in YAML as::

    name: my-study
    description: free text
    duration: 4.0                       # simulated seconds per run
    physics_dt: 6.25e-5                 # physics step of every env (default 1/16 ms; null:
                                        # each robot's own default), see below
    seeds: [0, 1]                       # env reset seeds (task sampling and sensor noise)
    envs:
      - TwoLinkElastic-v0               # an id (the "elastic_gym/" prefix is optional), or
      - id: elastic_gym/KR15Elastic-v0
        label: kr15-5deg
        kwargs: {task: tracking, task_options: {waypoints: [[0.1, 0.2, -0.3]]}}
        reset_options: {initial_state: {q: [0, 0.2, -0.3]}}
    axes:                               # robustness axes: each value is a set of env kwargs
      plant:                            # (deep-merged into every env entry's kwargs)
        - {label: nominal}
        - {label: mass+30%, plant_scaling: {link_mass: 1.3}}
      encoder:
        - {}
        - {encoder: {resolution: 1.0e-3}}
      mass:                             # an axis generated from magnitudes of one parameter
        parameter: plant_scaling.link_mass    # dotted path into the env kwargs
        values: [1.1, 1.3]              # or range: [1.0, 1.5] with num: 6 (log: true: geometric)
    sweeps:                             # one-at-a-time sweeps (curves and margins): the runs of
      link_mass:                        # the grid above are the nominal runs, and each sweep
        parameter: plant_scaling.link_mass    # adds runs that change only its parameter
        nominal: 1.0                    # the magnitude the nominal runs have
        range: [1.0, 2.0]
        num: 6
      delay: {parameter: sensor_delay, nominal: 0, values: [1, 2, 3, 5]}
    model_errors:                       # error of the controller's and observer's model:
      - {}                              # env.unwrapped.model.perturbed(**values)
      - {label: K-10%, stiffness: 0.9}
    controllers:
      - feedforward-state-feedback      # a registry name, or
      - name: motor-pd
        label: motor-only
        options: {}                     # constructor options
        sources: [finite-difference]    # pair only with these state-source labels
      - name: my-pd                     # a class not in the registry ("module:Class")
        class: mypackage.control:MyPD
    state_sources:
      - true                            # the truth (oracle); YAML's bare `true` is accepted
      - deluca                          # an observer registry name, or
      - name: ekf
        label: ekf-acc
        options: {use_accelerometers: true}
        initial_estimate: [...]         # full state vector, overrides the observer's own

Axes combine as a product. ``sweeps`` do not: they become one more axis named
``sweep`` whose values are ``nominal`` (the runs as given) and ``<name>=<magnitude>``
for each magnitude of each sweep (a magnitude equal to the sweep's ``nominal`` is the
nominal run itself, run once for all sweeps), so N sweeps of k magnitudes cost
1 + N k runs per loop instead of k^N. :mod:`~elastic_gym.evaluation.curves` and
:mod:`~elastic_gym.evaluation.margins` turn them into metric-versus-magnitude curves
and robustness margins.

Physics step. PyBullet integrates the links with first-order semi-implicit Euler and
the elastic transmissions are integrated the same way, so a closed loop's tracking
error carries an O(physics_dt) integration error. Measured on eq. (13) with the true
state tracking a nominal TwoLinkElastic motion: 9.1e-5 rad RMS at the robots' default
0.5 ms step, 4.8e-5 / 3.1e-5 / 2.6e-5 at 0.25 / 0.125 / 0.0625 ms. Comparisons
therefore default to ``COMPARISON_PHYSICS_DT`` = 1/16 ms, where the reported metrics
agree within 20 % with those at 1/8 of that step
(:mod:`~elastic_gym.evaluation.convergence` checks a scenario). An env entry's or
axis value's own ``physics_dt`` kwarg takes precedence.

Loading validates structure, types and registry names and raises
:class:`ScenarioError` (a ``ValueError``) naming the offending field, e.g.
``controllers[1].name``. Whether the module behind a registered name is available,
and whether an observer or controller applies to an env's arm (elastic or rigid), is
decided when the runs are planned (:func:`elastic_gym.evaluation.runner.plan_runs`):
inapplicable combinations are skipped, not errors.
"""

from __future__ import annotations

import importlib
import inspect
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import elastic_gym  # noqa: F401 - registers the env ids
from elastic_gym.controllers.registry import CONTROLLERS
from elastic_gym.evaluation.open_loop import BUILTIN_CONTROLLERS
from elastic_gym.evaluation.output import folder_name_problem
from elastic_gym.model import ParameterScaling
from elastic_gym.observers.registry import OBSERVERS
from elastic_gym.validation import ENV_NAMESPACE, is_real, registered_env_id
from elastic_gym.yaml_io import YAMLInputError, load_yaml

PRESET_DIR = Path(__file__).resolve().parent.parent / "presets"
DEFAULT_PRESET = "default"
TRUE_STATE = "true"
IDENTITY_COLUMNS = ("env", "model_error", "controller", "source", "seed")
SWEEP_AXIS = "sweep"
QUICK_DURATION = 0.5  # s, Scenario.quick()
NOMINAL = "nominal"
COMPARISON_PHYSICS_DT = 1.0 / 16000.0  # s; see the module docstring
MAX_PHYSICS_DT = 1e-3  # s, the envs' own bound

TOP_LEVEL_KEYS = (
    "name",
    "description",
    "duration",
    "physics_dt",
    "seeds",
    "envs",
    "axes",
    "sweeps",
    "model_errors",
    "controllers",
    "state_sources",
)
SWEEP_KEYS = ("parameter", "values", "range", "num", "log", "nominal")
ENV_KEYS = ("id", "label", "kwargs", "reset_options")
CONTROLLER_KEYS = ("name", "label", "options", "sources", "class")
SOURCE_KEYS = ("name", "label", "options", "initial_estimate", "class")


class ScenarioError(ValueError):
    """Invalid scenario; the message starts with the path of the offending field."""

    def __init__(self, path: str, message: str) -> None:
        super().__init__(f"{path}: {message}")
        self.path = path


# ---------------------------------------------------------------------------- entries
@dataclass(frozen=True)
class EnvEntry:
    """One env of the grid: gym id, constructor kwargs and ``reset`` options."""

    id: str
    label: str
    kwargs: dict = field(default_factory=dict)
    reset_options: dict = field(default_factory=dict)


@dataclass(frozen=True)
class ControllerEntry:
    """A controller by registry name (or explicit class) with its options.

    ``cls`` (a :class:`~elastic_gym.controllers.Controller` subclass or a
    ``"module:Class"`` string) bypasses the registry; ``sources`` restricts the state
    sources (by label) this controller is paired with (``None``: all).
    """

    name: str
    label: str
    options: dict = field(default_factory=dict)
    sources: tuple[str, ...] | None = None
    cls: type | str | None = None


@dataclass(frozen=True)
class SourceEntry:
    """A state source: ``"true"`` (the oracle) or an observer with options.

    ``initial_estimate`` (full state vector) is passed to ``observer.reset``.
    """

    name: str
    label: str
    options: dict = field(default_factory=dict)
    initial_estimate: tuple[float, ...] | None = None
    cls: type | str | None = None


@dataclass(frozen=True)
class Variation:
    """One value of an axis: env kwargs (robustness axes) or scaling factors (model errors)."""

    label: str
    values: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Sweep:
    """Magnitudes of one parameter: ``parameter`` is a dotted path into the env kwargs
    (``plant_scaling.link_mass``, ``encoder.noise_std``, ``sensor_delay``)."""

    name: str
    parameter: str
    values: tuple[float, ...]
    nominal: float | None = None
    log: bool = False

    def label(self, value: float) -> str:
        """Label of a magnitude in the ``sweep`` axis; ``"nominal"`` for the nominal one."""
        return NOMINAL if value == self.nominal else f"{self.name}={value:g}"

    def kwargs(self, value: float) -> dict:
        """The env kwargs that set the parameter to ``value``."""
        out: Any = value
        for key in reversed(self.parameter.split(".")):
            out = {key: out}
        return out

    def extremes(self) -> tuple[float, ...]:
        """The farthest magnitude below and above the nominal (those that exist)."""
        below = [v for v in self.values if self.nominal is not None and v < self.nominal]
        above = [v for v in self.values if self.nominal is None or v > self.nominal]
        return tuple(
            v for v in (min(below, default=None), max(above, default=None)) if v is not None
        )

    def variations(self) -> tuple[Variation, ...]:
        """The values of the ``sweep`` axis this sweep adds (not the nominal)."""
        return tuple(
            Variation(self.label(v), self.kwargs(v)) for v in self.values if v != self.nominal
        )

    def magnitude(self, label: str) -> float | None:
        """The magnitude of a ``sweep`` axis label of this sweep (None if not one)."""
        if label == NOMINAL:
            return self.nominal
        return next((v for v in self.values if self.label(v) == label), None)


@dataclass(frozen=True)
class Scenario:
    """A validated comparison grid; build it with :meth:`from_dict` or the loaders below."""

    name: str
    envs: tuple[EnvEntry, ...]
    controllers: tuple[ControllerEntry, ...]
    state_sources: tuple[SourceEntry, ...]
    duration: float = 3.0
    seeds: tuple[int, ...] = (0,)
    axes: tuple[tuple[str, tuple[Variation, ...]], ...] = ()
    model_errors: tuple[Variation, ...] = (Variation("exact"),)
    description: str = ""
    physics_dt: float | None = COMPARISON_PHYSICS_DT
    sweeps: tuple[Sweep, ...] = ()

    @classmethod
    def from_dict(cls, data: Mapping, name: str | None = None) -> Scenario:
        """Validate a mapping (parsed YAML, or Python objects) into a scenario."""
        return _parse(data, name)

    def with_overrides(
        self,
        *,
        seeds: Sequence[int] | None = None,
        duration: float | None = None,
        physics_dt: float | None = None,
    ) -> Scenario:
        """A copy with other seeds, duration and/or physics step (validated like the YAML
        fields)."""
        changes: dict[str, Any] = {}
        if seeds is not None:
            changes["seeds"] = _seeds(list(seeds), "seeds")
        if duration is not None:
            changes["duration"] = _positive(duration, "duration")
        if physics_dt is not None:
            changes["physics_dt"] = _physics_dt(physics_dt, "physics_dt")
        return replace(self, **changes)

    def quick(self) -> Scenario:
        """A fast look at the same grid: the first seed, at most ``QUICK_DURATION`` s per
        run, and each sweep thinned to its farthest magnitude on each side of the nominal."""
        sweeps = tuple(replace(w, values=w.extremes()) for w in self.sweeps)
        return replace(
            self,
            seeds=self.seeds[:1],
            duration=min(self.duration, QUICK_DURATION),
            sweeps=sweeps,
            axes=with_sweep_axis(self.axes, sweeps),
        )

    def env_kwargs(self, env: EnvEntry, variations: Sequence[Variation] = ()) -> dict:
        """Kwargs of ``env`` under axis values ``variations``: the scenario's physics step,
        then the entry's kwargs, then each variation, deep-merged in that order."""
        kwargs = {} if self.physics_dt is None else {"physics_dt": self.physics_dt}
        kwargs = merge(kwargs, env.kwargs)
        for variation in variations:
            kwargs = merge(kwargs, variation.values)
        return kwargs

    @property
    def axis_names(self) -> tuple[str, ...]:
        return tuple(name for name, _ in self.axes)

    @property
    def identity_columns(self) -> tuple[str, ...]:
        """Columns that identify a run: env, the axes, model error, controller, source, seed."""
        return (IDENTITY_COLUMNS[0], *self.axis_names, *IDENTITY_COLUMNS[1:])

    def to_dict(self) -> dict:
        """Plain-data form (YAML-serialisable; classes as ``"module:Class"``)."""
        return _plain(
            {
                "name": self.name,
                "description": self.description,
                "duration": self.duration,
                "physics_dt": self.physics_dt,
                "seeds": list(self.seeds),
                "envs": [
                    {
                        "id": e.id,
                        "label": e.label,
                        "kwargs": e.kwargs,
                        "reset_options": e.reset_options,
                    }
                    for e in self.envs
                ],
                "axes": {
                    name: [{"label": v.label, **v.values} for v in values]
                    for name, values in self.axes
                    if not (self.sweeps and name == SWEEP_AXIS)
                },
                "sweeps": {
                    w.name: _without_none(
                        {
                            "parameter": w.parameter,
                            "values": list(w.values),
                            "nominal": w.nominal,
                            "log": w.log,
                        }
                    )
                    for w in self.sweeps
                },
                "model_errors": [{"label": v.label, **v.values} for v in self.model_errors],
                "controllers": [
                    _without_none(
                        {
                            "name": c.name,
                            "label": c.label,
                            "options": c.options,
                            "sources": list(c.sources) if c.sources else None,
                            "class": _class_path(c.cls),
                        }
                    )
                    for c in self.controllers
                ],
                "state_sources": [
                    _without_none(
                        {
                            "name": s.name,
                            "label": s.label,
                            "options": s.options,
                            "initial_estimate": list(s.initial_estimate)
                            if s.initial_estimate is not None
                            else None,
                            "class": _class_path(s.cls),
                        }
                    )
                    for s in self.state_sources
                ],
            }
        )


# ---------------------------------------------------------------------------- loaders
def list_presets() -> list[str]:
    """Names of the presets shipped in ``elastic_gym/presets``."""
    return sorted(path.stem for path in PRESET_DIR.glob("*.yaml"))


def preset_path(name: str) -> Path:
    if name not in list_presets():
        raise ValueError(f"unknown preset {name!r}; valid: {list_presets()}")
    return PRESET_DIR / f"{name}.yaml"


def load_preset(name: str = DEFAULT_PRESET) -> Scenario:
    """A shipped preset by name (``elastic-gym compare --preset NAME``)."""
    return load_scenario(preset_path(name), name=name)


def load_scenario(path: str | Path, name: str | None = None) -> Scenario:
    """A scenario from a YAML file; the name defaults to the file's ``name`` field or stem."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"scenario file {str(path)!r} does not exist")
    try:
        data = load_yaml(path)
    except YAMLInputError as exc:
        raise ScenarioError(exc.where, exc.problem) from None
    if not isinstance(data, Mapping):
        raise ScenarioError(str(path), "the file must contain a mapping of scenario fields")
    return _parse(data, name or data.get("name") or path.stem)


def resolve_class(cls: type | str, path: str) -> type:
    """A class given directly or as ``"module:Class"``, which imports the module (running
    its top-level code: a scenario file is code, load only trusted ones)."""
    if isinstance(cls, type):
        return cls
    if not isinstance(cls, str):
        raise ScenarioError(path, f"must be a class or 'module:Class', got {cls!r}")
    module, _, attr = cls.partition(":")
    try:
        found = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as exc:
        raise ScenarioError(path, f"cannot import class {cls!r}: {exc}") from None
    except (Exception, SystemExit) as exc:  # the module's own code failed or does not compile
        message = " ".join(str(exc).split())
        raise ScenarioError(
            path, f"importing module {module!r} failed: {type(exc).__name__}: {message}"
        ) from None
    if not isinstance(found, type):
        raise ScenarioError(path, f"{cls!r} is not a class but {type(found).__name__} {found!r}")
    return found


# ---------------------------------------------------------------------------- parsing
def _parse(data: Mapping, name: str | None) -> Scenario:
    if not isinstance(data, Mapping):
        raise ScenarioError("scenario", f"must be a mapping, got {type(data).__name__}")
    _check_keys(data, TOP_LEVEL_KEYS, "scenario")
    for key in ("envs", "controllers", "state_sources"):
        if key not in data:
            raise ScenarioError(key, "is required")
    scenario_name = name or data.get("name") or "scenario"
    if not isinstance(scenario_name, str):
        raise ScenarioError("name", f"must be a string, got {scenario_name!r}")
    problem = folder_name_problem(scenario_name)
    if problem:
        raise ScenarioError("name", f"{problem} (it names the output folder compare_out/<name>)")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ScenarioError("description", "must be a string")
    envs = tuple(_env(item, f"envs[{i}]") for i, item in enumerate(_list(data["envs"], "envs")))
    sources = tuple(
        _source(item, f"state_sources[{i}]")
        for i, item in enumerate(_list(data["state_sources"], "state_sources"))
    )
    _unique_labels([s.label for s in sources], "state_sources")
    controllers = tuple(
        _controller(item, f"controllers[{i}]", {s.label for s in sources})
        for i, item in enumerate(_list(data["controllers"], "controllers"))
    )
    _unique_labels([c.label for c in controllers], "controllers")
    _unique_labels([e.label for e in envs], "envs")
    axes = _axes(data.get("axes", {}), envs)
    sweeps = _sweeps(data.get("sweeps", {}), envs)
    errors = tuple(
        _model_error(item, f"model_errors[{i}]")
        for i, item in enumerate(_list(data.get("model_errors", [{}]), "model_errors"))
    )
    _unique_labels([v.label for v in errors], "model_errors")
    return Scenario(
        name=scenario_name,
        description=description,
        duration=_positive(data.get("duration", 3.0), "duration"),
        physics_dt=_physics_dt(data.get("physics_dt", COMPARISON_PHYSICS_DT), "physics_dt"),
        seeds=_seeds(data.get("seeds", [0]), "seeds"),
        envs=envs,
        axes=with_sweep_axis(axes, sweeps),
        sweeps=sweeps,
        model_errors=errors,
        controllers=controllers,
        state_sources=sources,
    )


def _env(item: Any, path: str) -> EnvEntry:
    if isinstance(item, str):
        item = {"id": item}
    item = _mapping(item, path)
    _check_keys(item, ENV_KEYS, path)
    if "id" not in item:
        raise ScenarioError(f"{path}.id", "is required")
    env_id = _env_id(item["id"], f"{path}.id")
    kwargs = _mapping(item.get("kwargs", {}), f"{path}.kwargs")
    _check_env_kwargs(env_id, kwargs, f"{path}.kwargs")
    label = _label(
        item.get("label", env_id.removeprefix(ENV_NAMESPACE).removesuffix("-v0")), f"{path}.label"
    )
    reset_options = _mapping(item.get("reset_options", {}), f"{path}.reset_options")
    return EnvEntry(env_id, label, dict(kwargs), dict(reset_options))


def _env_id(value: Any, path: str) -> str:
    try:
        return registered_env_id(value)
    except ValueError as exc:
        raise ScenarioError(path, str(exc)) from None


def env_parameters(env_id: str) -> set[str]:
    """Constructor keyword names of a registered env (following ``**kwargs`` up the MRO)."""
    entry = gym.spec(env_id).entry_point
    if isinstance(entry, str):
        module, _, attr = entry.partition(":")
        entry = getattr(importlib.import_module(module), attr)
    names: set[str] = set()
    for klass in entry.__mro__ if isinstance(entry, type) else ():
        if "__init__" not in vars(klass):
            continue
        params = inspect.signature(klass.__init__).parameters.values()
        names |= {p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
        if not any(p.kind is p.VAR_KEYWORD for p in params):
            break
    names.discard("self")
    return names


def _check_env_kwargs(env_id: str, kwargs: Mapping, path: str) -> None:
    unknown = set(kwargs) - env_parameters(env_id)
    if unknown:
        raise ScenarioError(
            path,
            f"unknown env kwarg(s) {sorted(unknown)} for {env_id}; "
            f"valid: {sorted(env_parameters(env_id))}",
        )
    if "plant_scaling" in kwargs:
        try:
            ParameterScaling.from_config(kwargs["plant_scaling"])
        except (TypeError, ValueError) as exc:
            raise ScenarioError(f"{path}.plant_scaling", str(exc)) from None


def _controller(item: Any, path: str, source_labels: set[str]) -> ControllerEntry:
    if isinstance(item, str):
        item = {"name": item}
    item = _mapping(item, path)
    _check_keys(item, CONTROLLER_KEYS, path)
    name = _name(item, path)
    cls = _class_field(item.get("class"), f"{path}.class")
    valid = sorted({*CONTROLLERS, *BUILTIN_CONTROLLERS})
    if cls is None and name not in valid:
        raise ScenarioError(f"{path}.name", f"unknown controller {name!r}; valid: {valid}")
    sources = item.get("sources")
    if sources is not None:
        sources = tuple(
            _label(s, f"{path}.sources[{i}]")
            for i, s in enumerate(_list(sources, f"{path}.sources"))
        )
        missing = sorted(set(sources) - source_labels)
        if missing:
            raise ScenarioError(
                f"{path}.sources",
                f"unknown state source label(s) {missing}; valid: {sorted(source_labels)}",
            )
    return ControllerEntry(
        name=name,
        label=_label(item.get("label", name), f"{path}.label"),
        options=dict(_mapping(item.get("options", {}), f"{path}.options")),
        sources=sources,
        cls=cls,
    )


def _source(item: Any, path: str) -> SourceEntry:
    if item is True or isinstance(item, str):
        item = {"name": TRUE_STATE if item is True else item}
    item = _mapping(item, path)
    _check_keys(item, SOURCE_KEYS, path)
    name = _name(item, path)
    cls = _class_field(item.get("class"), f"{path}.class")
    if cls is None and name not in OBSERVERS:
        raise ScenarioError(
            f"{path}.name", f"unknown state source {name!r}; valid: {sorted(OBSERVERS)}"
        )
    estimate = item.get("initial_estimate")
    if estimate is not None:
        estimate = tuple(
            _number(v, f"{path}.initial_estimate[{i}]")
            for i, v in enumerate(_list(estimate, f"{path}.initial_estimate"))
        )
    return SourceEntry(
        name=name,
        label=_label(item.get("label", name), f"{path}.label"),
        options=dict(_mapping(item.get("options", {}), f"{path}.options")),
        initial_estimate=estimate,
        cls=cls,
    )


def _axis_name(name: Any, path: str) -> str:
    reserved = [*IDENTITY_COLUMNS, SWEEP_AXIS]
    if not isinstance(name, str) or not name.isidentifier() or name in reserved:
        raise ScenarioError(path, f"names must be identifiers other than {reserved}, got {name!r}")
    return name


def _axes(data: Any, envs: tuple[EnvEntry, ...]) -> tuple[tuple[str, tuple[Variation, ...]], ...]:
    axes = _mapping(data, "axes")
    out = []
    for axis, items in axes.items():
        path = f"axes.{_axis_name(axis, f'axes.{axis}')}"
        if isinstance(items, Mapping):  # generated from the magnitudes of one parameter
            values = [
                Variation(f"{axis}={v:g}", w.kwargs(v))
                for w in [_sweep(axis, items, path, envs, nominal_required=False)]
                for v in w.values
            ]
        else:
            values = [
                _variation(item, f"{path}[{i}]", NOMINAL)
                for i, item in enumerate(_list(items, path))
            ]
            for i, value in enumerate(values):
                for env in envs:
                    _check_env_kwargs(env.id, value.values, f"{path}[{i}]")
        _unique_labels([v.label for v in values], path)
        out.append((axis, tuple(values)))
    return tuple(out)


def _sweeps(data: Any, envs: tuple[EnvEntry, ...]) -> tuple[Sweep, ...]:
    return tuple(
        _sweep(name, item, f"sweeps.{_axis_name(name, f'sweeps.{name}')}", envs)
        for name, item in _mapping(data, "sweeps").items()
    )


def _sweep(
    name: str, data: Any, path: str, envs: tuple[EnvEntry, ...], nominal_required: bool = True
) -> Sweep:
    """One parameter's magnitudes: ``values``, or ``range`` + ``num`` (``log``: geometric)."""
    data = _mapping(data, path)
    _check_keys(data, SWEEP_KEYS, path)
    parameter = data.get("parameter")
    keys = parameter.split(".") if isinstance(parameter, str) else []
    if not keys or not all(k.isidentifier() for k in keys):
        raise ScenarioError(
            f"{path}.parameter",
            "must be a dotted path into the env kwargs, "
            f"e.g. 'plant_scaling.link_mass', got {parameter!r}",
        )
    log = data.get("log", False)
    if not isinstance(log, bool):
        raise ScenarioError(f"{path}.log", f"must be true or false, got {log!r}")
    if ("values" in data) == ("range" in data):
        raise ScenarioError(path, "give either 'values' or 'range' (with 'num')")
    if "values" in data:
        if "num" in data:
            raise ScenarioError(f"{path}.num", "goes with 'range', not with 'values'")
        values = [
            _number(v, f"{path}.values[{i}]")
            for i, v in enumerate(_list(data["values"], f"{path}.values"))
        ]
        values = [
            int(v) if isinstance(raw, int) else v  # integer parameters stay integers
            for v, raw in zip(values, data["values"], strict=True)
        ]
    else:
        values = _range(data, path, log)
    for i, v in enumerate(values):
        if not math.isfinite(v) or (log and v <= 0):
            raise ScenarioError(
                f"{path}.values[{i}]", f"must be finite{' and > 0' if log else ''}, got {v!r}"
            )
    _unique_labels([f"{v:g}" for v in values], f"{path}.values")
    nominal = data.get("nominal")
    if nominal is None and nominal_required:
        raise ScenarioError(f"{path}.nominal", "is required: the magnitude of the nominal runs")
    if nominal is not None:
        nominal = _number(nominal, f"{path}.nominal")
    sweep = Sweep(name, parameter, tuple(values), nominal, log)
    for variation in sweep.variations():
        for env in envs:
            _check_env_kwargs(env.id, variation.values, f"{path}.parameter")
    return sweep


def _range(data: Mapping, path: str, log: bool) -> list[float]:
    bounds = _list(data["range"], f"{path}.range")
    if len(bounds) != 2:
        raise ScenarioError(f"{path}.range", f"must be [low, high], got {bounds!r}")
    low, high = (_number(b, f"{path}.range[{i}]") for i, b in enumerate(bounds))
    num = data.get("num")
    if isinstance(num, bool) or not isinstance(num, int) or num < 2:
        raise ScenarioError(f"{path}.num", f"must be an integer >= 2 with 'range', got {num!r}")
    if log and not (low > 0 and high > 0):
        raise ScenarioError(f"{path}.range", f"log: true needs bounds > 0, got {bounds!r}")
    points = np.geomspace(low, high, num) if log else np.linspace(low, high, num)
    return [float(f"{v:.12g}") for v in points]  # 1.2000000000000002 -> 1.2


def _model_error(item: Any, path: str) -> Variation:
    variation = _variation(item, path, "exact")
    try:
        ParameterScaling.from_config(dict(variation.values))
    except (TypeError, ValueError) as exc:
        raise ScenarioError(path, str(exc)) from None
    return variation


def _variation(item: Any, path: str, empty_label: str) -> Variation:
    values = dict(_mapping(item, path))
    label = values.pop("label", None)
    if label is None:
        label = format_values(values) or empty_label
    return Variation(_label(label, f"{path}.label"), values)


def with_sweep_axis(axes: tuple, sweeps: tuple[Sweep, ...]) -> tuple:
    """``axes`` (without a ``sweep`` axis) plus the ``sweep`` axis of ``sweeps``, if any."""
    axes = tuple((name, values) for name, values in axes if name != SWEEP_AXIS)
    if not sweeps:
        return axes
    return (*axes, (SWEEP_AXIS, (Variation(NOMINAL), *(v for w in sweeps for v in w.variations()))))


# ---------------------------------------------------------------------------- helpers
def format_values(values: Mapping, prefix: str = "") -> str:
    """Compact label of (nested) values: ``plant_scaling.link_mass=1.3,task=tracking``."""
    parts = []
    for key, value in values.items():
        if isinstance(value, Mapping):
            parts.append(format_values(value, f"{prefix}{key}."))
        else:
            parts.append(f"{prefix}{key}={value}")
    return ",".join(p for p in parts if p)


def merge(base: Mapping, override: Mapping) -> dict:
    """Recursive dict merge: mappings are merged, anything else is replaced."""
    out = dict(base)
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def _plain(value: Any) -> Any:
    """Nested lists/dicts/numbers/strings only (tuples and arrays as lists, others as str)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if hasattr(value, "tolist"):  # numpy arrays and scalars
        return _plain(value.tolist())
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


def _class_path(cls: type | str | None) -> str | None:
    if cls is None or isinstance(cls, str):
        return cls
    return f"{cls.__module__}:{cls.__qualname__}"


def _without_none(data: dict) -> dict:
    return {k: v for k, v in data.items() if v is not None}


def _check_keys(data: Mapping, allowed: Sequence[str], path: str) -> None:
    unknown = [k for k in data if k not in allowed]
    if unknown:
        raise ScenarioError(
            f"{path}.{unknown[0]}" if path != "scenario" else str(unknown[0]),
            f"unknown field; valid: {list(allowed)}",
        )


def _mapping(value: Any, path: str) -> Mapping:
    if not isinstance(value, Mapping):
        raise ScenarioError(path, f"must be a mapping, got {type(value).__name__}")
    return value


def _list(value: Any, path: str) -> list:
    if not isinstance(value, (list, tuple)) or not value:
        raise ScenarioError(path, f"must be a non-empty list, got {value!r}")
    return list(value)


def _name(item: Mapping, path: str) -> str:
    if "name" not in item:
        raise ScenarioError(f"{path}.name", "is required")
    name = item["name"]
    if name is True:
        return TRUE_STATE
    if not isinstance(name, str) or not name:
        raise ScenarioError(f"{path}.name", f"must be a non-empty string, got {name!r}")
    return name


def _class_field(value: Any, path: str) -> type | str | None:
    if value is None or isinstance(value, type):
        return value
    if not isinstance(value, str) or ":" not in value:
        raise ScenarioError(path, f"must be a class or a 'module:Class' string, got {value!r}")
    return value


def _label(value: Any, path: str) -> str:
    if value is True:
        return TRUE_STATE
    if not isinstance(value, (str, int, float)) or isinstance(value, bool) or value == "":
        raise ScenarioError(path, f"must be a non-empty string, got {value!r}")
    return str(value)


def _unique_labels(labels: list[str], path: str) -> None:
    duplicates = sorted({x for x in labels if labels.count(x) > 1})
    if duplicates:
        raise ScenarioError(path, f"duplicate label(s) {duplicates}; give each entry a 'label'")


def _number(value: Any, path: str) -> float:
    if isinstance(value, bool) or not is_real(value):
        raise ScenarioError(path, f"must be a number, got {value!r}")
    return float(value)


def _positive(value: Any, path: str) -> float:
    number = _number(value, path)
    if not number > 0 or number == float("inf"):
        raise ScenarioError(path, f"must be a finite number > 0, got {value!r}")
    return number


def _physics_dt(value: Any, path: str) -> float | None:
    """A physics step in (0, 1 ms], or None (each env's own default)."""
    if value is None:
        return None
    number = _positive(value, path)
    if number > MAX_PHYSICS_DT:
        raise ScenarioError(path, f"must be <= {MAX_PHYSICS_DT} s, got {value!r}")
    return number


def _seeds(value: Any, path: str) -> tuple[int, ...]:
    single = isinstance(value, int) and not isinstance(value, bool)
    items = [value] if single else _list(value, path)
    for i, seed in enumerate(items):
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ScenarioError(f"{path}[{i}]", f"must be an integer >= 0, got {seed!r}")
    duplicates = sorted({seed for seed in items if items.count(seed) > 1})
    if duplicates:
        raise ScenarioError(
            path,
            f"duplicate seed(s) {duplicates}: a seed repeated would "
            "count the same run twice in the means over seeds",
        )
    return tuple(items)
