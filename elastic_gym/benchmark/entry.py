"""Benchmark entries: what is scored, and what it reads.

An entry is a closed loop of the comparison runner: a **controller** (registry name, a
user's `Controller` subclass as ``"module:Class"``, or any callable policy through the
``policy`` controller) with its ``options``, paired with a **state source** (``"true"``,
an observer registry name, a user's `Observer` subclass, or raw ``"sensors"`` for a
controller that reads them); or a **policy folder** (``run``: an exported policy, or with
``trust_pickle`` a run folder of ``elastic-gym train``), the ``trained-policy`` controller
on the policy's own state source, raw sensors included.

The controller sees only the estimate, the reference and the time; the observer sees the
sensors, the applied torque and the ground-truth items its class declares in
``privileged``. An entry whose source reads any ground truth is an **oracle reference**,
scored like any entry and listed apart (`describe_entry` records what it used).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

from pydantic import AfterValidator, Field, PrivateAttr, StrictStr, model_validator

from elastic_gym.benchmark.card import checked_label
from elastic_gym.evaluation.scenario import (
    ControllerEntry,
    SourceEntry,
    resolve_class,
)
from elastic_gym.evaluation.scenario_models import ClassPath
from elastic_gym.model.identified import checked_model_file
from elastic_gym.observers.registry import OBSERVERS, source_class
from elastic_gym.validation import StrictModel, at_most_one, only_when

TRUE_STATE = "true"
TRAINED_POLICY = "trained-policy"
DEFAULT_CONTROLLER = "feedforward-state-feedback"


def _registered(check: Callable[[str], Any]) -> Callable[[Any], Any]:
    """A validator checking a registry name with ``check`` (a class or a class path
    passes: it is resolved when the runs are planned)."""

    def validate(value: Any) -> Any:
        if value is not None and not _is_class_path(value):
            check(value)
        return value

    return validate


def _controller_class(name: str) -> type:
    from elastic_gym.evaluation.controllers import comparison_controller

    return comparison_controller(name)


class Entry(StrictModel):
    """One entry (module docstring): ``controller`` + ``source``, or ``run``.

    ``label`` names the entry on the leaderboard (default: ``<controller>@<source>`` or the
    run folder's name, ``+identified`` appended when ``models`` are given). ``models``:
    identified model files (`elastic-gym identify`) the controller and observer build on,
    one per robot, instead of the nominal model.
    """

    label: Annotated[str, AfterValidator(checked_label)] | None = None
    controller: Annotated[
        StrictStr | type | None, AfterValidator(_registered(_controller_class))
    ] = None
    options: dict[str, Any] = Field(default_factory=dict)
    source: Annotated[StrictStr | type, AfterValidator(_registered(source_class))] = TRUE_STATE
    source_options: dict[str, Any] = Field(default_factory=dict)
    run: str | None = None
    best: bool = False
    models: tuple[Annotated[StrictStr, AfterValidator(checked_model_file)], ...] = ()
    trust_pickle: bool = False

    @model_validator(mode="after")
    def _one_kind(self) -> Entry:
        at_most_one({"controller": self.controller, "run": self.run}, required=True)
        only_when(
            self.run is None,
            {"options": self.options, "source_options": self.source_options},
            "a controller is named (a policy folder has them)",
        )
        only_when(self.run is not None, {"trust_pickle": self.trust_pickle}, "run is given")
        return self

    @property
    def name(self) -> str:
        if self.label is not None:
            return self.label
        suffix = "+identified" if self.models else ""  # apart from the nominal model's
        if self.run is not None:
            return Path(self.run).name + suffix
        return f"{_short(self.controller)}@{_short(self.source)}{suffix}"


def described(value: str | type | None) -> str | None:
    """A controller or source as a command line names it: its registry name, or a class
    as ``module:Class`` (``None`` for a class no import can find: one defined in a
    function)."""
    if not isinstance(value, type):
        return value
    if "<locals>" in value.__qualname__:
        return None
    return f"{value.__module__}:{value.__qualname__}"


def _short(value: str | type | None) -> str:
    return value.__name__ if isinstance(value, type) else str(value).rpartition(":")[2]


def _is_class_path(value: str | type | None) -> bool:
    return isinstance(value, type) or ":" in str(value)


def class_kind(path: str, option: str) -> str:
    """``"controller"`` or ``"observer"``: what the ``"module:Class"`` at ``path`` is."""
    from elastic_gym.controllers.base import Controller
    from elastic_gym.observers.base import Observer

    cls = resolve_class(path, option, (Controller, Observer))
    return "controller" if issubclass(cls, Controller) else "observer"


class EntryArguments(StrictModel):
    """The entry options of ``elastic-gym benchmark``, checked together once: one of
    ``--leaderboard``, ``--verify``, ``--upgrade``, ``--run`` or a closed loop
    (``--controller`` / ``--class`` / ``--source``); ``--class`` (``cls``) takes the place
    of the controller or of the source, whichever it is. `entry` gives the `Entry` fields."""

    controller: str | None = None
    cls: ClassPath = Field(default=None, alias="class")
    source: str | None = None
    run: str | None = None
    trust_pickle: bool = False
    leaderboard: bool = False
    verify: str | None = None
    upgrade: list[str] | None = None
    options: dict[str, Any] = Field(default_factory=dict)
    source_options: dict[str, Any] = Field(default_factory=dict)
    label: Annotated[str, AfterValidator(checked_label)] | None = None
    model: list[str] | None = None
    _class_kind: str = PrivateAttr("")

    @model_validator(mode="after")
    def _one_kind(self) -> EntryArguments:
        loop = self.controller or self.cls or self.source
        kinds = {
            "--leaderboard": self.leaderboard or None,
            "--verify": self.verify,
            "--upgrade": self.upgrade,
            "--run": self.run,
        }
        at_most_one({**kinds, "--controller/--class/--source": loop}, required=True)
        if self.cls is not None:
            self._class_kind = class_kind(self.cls, "--class")
            taken = "source" if self._class_kind == "observer" else "controller"
            kind = {"observer": "--class (an Observer)", "controller": "--class (a Controller)"}
            at_most_one({kind[self._class_kind]: self.cls, f"--{taken}": getattr(self, taken)})
        only_when(self.run is not None, {"--trust-pickle": self.trust_pickle}, "--run is given")
        return self

    def entry(self) -> dict[str, Any]:
        """The `Entry` fields (defaults: `DEFAULT_CONTROLLER`, the true state)."""
        fields: dict[str, Any] = {"options": self.options, "source_options": self.source_options}
        fields |= {"label": self.label} if self.label else {}
        fields |= {"models": tuple(self.model)} if self.model else {}
        if self.run is not None:
            return {"run": self.run, "trust_pickle": self.trust_pickle, **fields}
        given = {self._class_kind: self.cls} if self.cls is not None else {}
        controller = given.get("controller", self.controller) or DEFAULT_CONTROLLER
        return {
            "controller": controller,
            "source": given.get("observer", self.source) or TRUE_STATE,
            **fields,
        }


def resolve_entry(entry: Entry) -> tuple[ControllerEntry, SourceEntry]:
    """The comparison's controller and state-source entries of ``entry`` (its names are
    checked by `Entry`; options are bound to the constructors when the runs are
    planned)."""
    if entry.run is not None:
        return _run_entries(entry)
    controller = entry.controller
    if _is_class_path(controller):
        name = _short(controller)
        c_entry = ControllerEntry(
            name=name, label=name, options=dict(entry.options), **{"class": controller}
        )
    else:
        name = str(controller)  # a registry name (Entry needs a controller or a run)
        c_entry = ControllerEntry(name=name, label=name, options=dict(entry.options))
    return c_entry, _source_entry(entry.source, entry.source_options)


def _source_entry(source: str | type, options: dict) -> SourceEntry:
    if _is_class_path(source):
        name = _short(source)
        return SourceEntry(name=name, label=name, options=dict(options), **{"class": source})
    return SourceEntry(name=source, label=source, options=dict(options))


def _run_entries(entry: Entry) -> tuple[ControllerEntry, SourceEntry]:
    from elastic_gym.policy.loading import is_exported, read_spec, untrusted

    run = Path(str(entry.run))
    if not is_exported(run) and (run / "config.yaml").is_file() and not entry.trust_pickle:
        raise ValueError(f"run: {untrusted(run)}")
    try:
        spec = read_spec(run)
    except (FileNotFoundError, ValueError) as exc:
        raise ValueError(f"run: {exc}") from None
    source = _source_entry(spec.state, dict(spec.observer_options))
    options: dict[str, Any] = {"policy": str(run.resolve())}
    options |= {"best": True} if entry.best else {}
    options |= {"trust_pickle": True} if entry.trust_pickle else {}
    return ControllerEntry(name=TRAINED_POLICY, label=run.name, options=options), source


def privileged_items(source: SourceEntry) -> tuple[str, ...]:
    """The ground-truth items the state source reads (empty: implementable; raw sensors
    read none)."""
    if source.cls is not None:
        cls = resolve_class(source.cls, "source")
        return tuple(getattr(cls, "privileged", ()))
    if source.name == TRUE_STATE:
        return ("true_state",)
    fixed = OBSERVERS[source.name][2] if source.name in OBSERVERS else {}
    if fixed.get("acceleration") == "ideal":
        return ("link_acceleration",)
    return tuple(getattr(source_class(source.name), "privileged", ()))


def describe_entry(entry: Entry) -> dict:
    """What the scorecard records about an entry: controller and source (name or class
    path, options), the run folder and what it was trained on, the ground truth it read
    (``privileged``), whether it is an ``oracle`` reference and the identified model files
    its controller and observer build on (``models``)."""
    controller, source = resolve_entry(entry)
    privileged = privileged_items(source)
    record: dict[str, Any] = {
        "label": entry.name,
        "kind": "run" if entry.run is not None else "controller",
        "controller": _described(controller.cls, controller.name),
        "controller_options": _as_given(_plain_options(controller.options), entry),
        "source": _described(source.cls, source.name),
        "source_options": _plain_options(source.options),
        "privileged": list(privileged),
        "oracle": bool(privileged),
        "models": list(entry.models),
    }
    if entry.run is not None:
        record["run"] = _run_record(Path(entry.run))
    return record


def _as_given(options: dict, entry: Entry) -> dict:
    """The options a card records: the run folder as the entry names it (a command from
    the same folder reproduces it; no absolute path of the machine that scored it), where
    the controller got it resolved."""
    if entry.run is None:
        return options
    resolved = str(Path(entry.run).resolve())
    return {key: entry.run if value == resolved else value for key, value in options.items()}


def _run_record(run: Path) -> dict[str, Any]:
    """What the scorecard says about a policy folder: its name, env, algorithm, state
    source, seed and steps (an exported policy's manifest, or a run's config.yaml)."""
    from elastic_gym.policy.loading import is_exported
    from elastic_gym.policy.manifest import read_manifest

    if is_exported(run):
        manifest = read_manifest(run)
        made = manifest.provenance
        return {
            "folder": run.name,
            "exported": True,
            "env_id": manifest.env_id,
            "algo": made.algo,
            "state": manifest.state,
            "seed": made.seed,
            "policy_steps": made.policy_steps,
            "env_kwargs": _plain_options(manifest.spec.env_kwargs),
            "graph_sha256": manifest.graph.sha256,
        }
    from elastic_gym.training.run_folder import RunFolder

    config = RunFolder(run).read_config()
    return {
        "folder": run.name,
        "env_id": config.env_id,
        "algo": config.algo,
        "state": config.state,
        "seed": config.seed,
        "total_steps": config.total_steps,
        "env_kwargs": _plain_options(config.env_kwargs),
    }


def _described(cls: type | str | None, name: str) -> str:
    if cls is None:
        return name
    return cls if isinstance(cls, str) else f"{cls.__module__}:{cls.__qualname__}"


def _plain_options(options: dict) -> dict:
    """Options as JSON data: objects (a callable policy) by their qualified name."""
    out: dict[str, Any] = {}
    for key, value in options.items():
        if isinstance(value, dict):
            out[key] = _plain_options(value)
        elif value is None or isinstance(value, (bool, int, float, str, list)):
            out[key] = value
        else:
            name = getattr(value, "__qualname__", type(value).__name__)
            out[key] = f"{getattr(value, '__module__', '?')}:{name}"
    return out
