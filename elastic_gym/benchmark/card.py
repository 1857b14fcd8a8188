"""The scorecard as data: a pydantic model of the JSON file, its compact text, and reading.

A card (``format`` 2): ``suite`` (name, version, sha256); ``entry`` (what was scored and
what it read); ``command`` (the `elastic-gym benchmark` line that reproduces it, from the
repository's root; ``null`` for a Python callable); ``robots``, ``seeds``; the ``scores``
it states (each finite, in [0, 1]); ``cells``: per cell ``robot/category/label`` the
episodes in columns, one list per field in seed order (``status`` and `METRICS`, ``null``
for a missing or non-finite value), from which every score is recomputed; ``provenance``
(package, commit, time, wall and CPU time): the only block two runs of one command differ
in. `read_scorecard` validates a file (errors name the file and the field); the checks
against a suite are `elastic_gym.benchmark.audit`'s.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    StrictFloat,
    StrictInt,
    field_validator,
    model_validator,
)

from elastic_gym.validation import FieldError, checked, distinct

FORMAT = 2
MAX_LABEL = 100  # characters of an entry label
MAX_CARD_BYTES = 16 * 2**20  # a full card is about 0.1 MB
METRICS = (  # the per-episode metrics a card keeps: the scores' and the card page's
    "track_rms",
    "track_max",
    "overshoot_pct",
    "settling_time",
    "torsion_max",
    "torque_rms",
    "torque_rate_rms",
    "saturation_share",
)

Score = Annotated[StrictFloat, Field(ge=0, le=1, allow_inf_nan=False)]
Metric = Annotated[StrictFloat, Field(ge=0, allow_inf_nan=False)] | None
Count = Annotated[StrictInt, Field(ge=0)]
Name = Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_.+%=-]+$")]


class Record(BaseModel):
    """Base of the card's models: unknown keys refused (``extra="forbid"``). A card is JSON
    data, so no numpy conversion (`elastic_gym.validation.StrictModel`'s) is needed."""

    model_config = ConfigDict(extra="forbid")


def checked_label(label: str) -> str:
    """An entry label: 1 to `MAX_LABEL` characters (it names the entry on the leaderboard
    and, made file-safe, its output folder)."""
    if not label:
        raise ValueError("the label is empty")
    if len(label) > MAX_LABEL:
        raise ValueError(
            f"the label is {len(label)} characters long, more than {MAX_LABEL} "
            f"(it starts {label[:24]!r})"
        )
    return label


class SuiteRef(Record):
    """The suite a card was scored on."""

    name: Name
    version: Annotated[StrictInt, Field(ge=1)]
    hash: str = Field(pattern=r"^[0-9a-f]{64}$")


class EntryRecord(Record):
    """What was scored (`elastic_gym.benchmark.entry.describe_entry`): controller and state
    source (registry names or ``module:Class``) with their options, the ground-truth items
    the source reads (``privileged``), whether that makes it an oracle reference, for a
    trained policy its training record (``run``), and the identified model files its
    controller and observer built on (``models``, as given; none: the nominal model)."""

    label: Annotated[str, AfterValidator(checked_label)]
    kind: Literal["controller", "run"]
    controller: str = Field(min_length=1)
    controller_options: dict[str, Any]
    source: str = Field(min_length=1)
    source_options: dict[str, Any]
    privileged: list[str]
    oracle: bool
    run: dict[str, Any] | None = None
    models: list[str] = Field(default_factory=list, exclude_if=lambda models: not models)


class ScoreRecord(Record):
    """The scores a card states (`elastic_gym.benchmark.scoring`); a category without an
    episode (robots left out) is ``null``."""

    overall: Score
    precision: Score
    categories: dict[Name, Score | None] = Field(min_length=1)
    per_robot: dict[Name, dict[Name, Score | None]] = Field(min_length=1)
    episodes: Count
    passed: Count

    @model_validator(mode="after")
    def _passed_of_episodes(self) -> ScoreRecord:
        if self.passed > self.episodes:
            raise ValueError(f"passed ({self.passed}) exceeds episodes ({self.episodes})")
        return self


class CellEpisodes(Record):
    """A cell's episodes in columns, one value per seed of the card (seed order)."""

    status: list[Annotated[str, Field(min_length=1)]]
    track_rms: list[Metric]
    track_max: list[Metric]
    overshoot_pct: list[Metric]
    settling_time: list[Metric]
    torsion_max: list[Metric]
    torque_rms: list[Metric]
    torque_rate_rms: list[Metric]
    saturation_share: list[Metric]

    def rows(self) -> Iterator[tuple[str, dict[str, float]]]:
        """``(status, metrics)`` per episode; a missing value as NaN."""
        columns = {m: getattr(self, m) for m in METRICS}
        for i, status in enumerate(self.status):
            yield status, {m: math.nan if c[i] is None else c[i] for m, c in columns.items()}


class Provenance(Record):
    """When, where and how long: the only part of a card two runs of a command differ in."""

    package: str
    commit: str | None = None
    created: str
    wall_time: Annotated[float, Field(ge=0, allow_inf_nan=False)]
    cpu_time: Annotated[float, Field(ge=0, allow_inf_nan=False)] | None = None
    note: str | None = None  # e.g. re-scored from an earlier run's table


class Scorecard(Record):
    """A scorecard (module docstring)."""

    format: Literal[2]
    suite: SuiteRef
    entry: EntryRecord
    command: str | None
    robots: list[Name] = Field(min_length=1)
    seeds: list[Annotated[StrictInt, Field(ge=0)]] = Field(min_length=1)
    scores: ScoreRecord
    cells: dict[str, CellEpisodes] = Field(min_length=1)
    provenance: Provenance

    @field_validator("format", mode="before")
    @classmethod
    def _known_format(cls, value: Any) -> Any:
        if value == 1 and not isinstance(value, bool):
            raise ValueError(
                "format 1 (per-episode records with repeated keys) is no longer read: "
                "upgrade the card with `elastic-gym benchmark --upgrade CARD`"
            )
        return value

    @field_validator("robots", "seeds")
    @classmethod
    def _distinct(cls, values: list) -> list:
        return list(distinct(values, "value(s)"))

    @model_validator(mode="after")
    def _columns_match_seeds(self) -> Scorecard:
        for cell_id, cell in self.cells.items():
            robot = cell_id.partition("/")[0]
            if robot not in self.robots:
                raise FieldError(
                    ("cells", cell_id),
                    f"robot {robot!r} is not among the card's robots {self.robots}",
                )
            for name in ("status", *METRICS):
                if len(getattr(cell, name)) != len(self.seeds):
                    raise FieldError(
                        ("cells", cell_id, name),
                        f"{len(getattr(cell, name))} values for the card's {len(self.seeds)} seeds",
                    )
        return self

    @property
    def label(self) -> str:
        return self.entry.label

    def episode_rows(self) -> Iterator[tuple[str, int, str, dict[str, float]]]:
        """``(cell id, seed, status, metrics)`` of every episode, in the card's order."""
        for cell_id, cell in self.cells.items():
            for seed, (status, metrics) in zip(self.seeds, cell.rows(), strict=True):
                yield cell_id, seed, status, metrics


def read_scorecard(path: str | Path) -> Scorecard:
    """A scorecard JSON file, validated: ``ValueError`` naming the file and the field."""
    path = Path(path)
    try:
        if path.stat().st_size > MAX_CARD_BYTES:
            raise ValueError(f"{path.stat().st_size} bytes, more than a scorecard's bound")
        data = json.loads(path.read_bytes())
    except (OSError, ValueError) as exc:  # JSONDecodeError and UnicodeDecodeError included
        raise ValueError(f"{path}: not a scorecard JSON file: {exc}") from None
    return parse_scorecard(data, str(path))


def parse_scorecard(data: Any, where: str = "scorecard") -> Scorecard:
    """A card from JSON data (``ValueError`` starting with ``where``)."""
    if not isinstance(data, dict):
        raise ValueError(f"{where}: not a scorecard (a JSON object), got {type(data).__name__}")
    try:
        return checked(lambda: Scorecard.model_validate(data), model=Scorecard)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def card_text(card: Scorecard) -> str:
    """The JSON text of a card: one key per line, each list of numbers or strings on one
    line (a cell's column), so that a diff of two cards shows which columns differ."""
    return _dump(card.model_dump(mode="json"), 0) + "\n"


def _dump(value: Any, depth: int) -> str:
    if isinstance(value, dict) and value:
        pad = " " * (depth + 1)
        items = [f"{pad}{json.dumps(k)}: {_dump(v, depth + 1)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + " " * depth + "}"
    if isinstance(value, list) and any(isinstance(v, (dict, list)) for v in value):
        pad = " " * (depth + 1)
        return (
            "[\n" + ",\n".join(pad + _dump(v, depth + 1) for v in value) + "\n" + " " * depth + "]"
        )
    return json.dumps(value, allow_nan=False, separators=(", ", ": "))


def card_schema() -> dict:
    """The JSON Schema of a scorecard file."""
    return Scorecard.model_json_schema()
