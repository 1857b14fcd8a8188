"""The leaderboard rebuilt from scorecard files: a page, a CSV and a figure; nothing is run.

`rebuild_leaderboard` reads every ``*.json`` of the scorecard folder, validates each card
(`elastic_gym.benchmark.card`) and checks it against the suite
(`elastic_gym.benchmark.audit`: its scores recomputed from its episodes, its oracle flag
derived), refuses two cards with one label, and only then writes the page
(`elastic_gym.benchmark.page`), the CSV and the figure, each atomically. It writes exactly
three files, at the paths it is given (defaults: ``docs/leaderboard.md`` and, in the
folder named like the page, ``leaderboard.csv`` and ``leaderboard.png``), and replaces a
file there only if an earlier rebuild wrote it (the page's first line, the CSV's header,
the figure's ``Software`` text), unless ``overwrite``. A ``notes.md`` beside the scorecard
folder (what the results show, in words) goes under the tables.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

from elastic_gym.benchmark.audit import CheckedCard, check_card
from elastic_gym.benchmark.card import read_scorecard
from elastic_gym.benchmark.markdown import plot_text
from elastic_gym.benchmark.page import MARKER, leaderboard_markdown, shown_label, tables
from elastic_gym.benchmark.scorecard import score_value
from elastic_gym.benchmark.scoring import OVERALL, PRECISION
from elastic_gym.benchmark.suite import DEFAULT_SUITE, SuiteConfig, load_suite
from elastic_gym.runtime.atomic import write_bytes, write_text

DOCS = Path("docs")
SCORECARD_DIR = DOCS / "leaderboard" / "scorecards"
PAGE = DOCS / "leaderboard.md"
NOTES = "notes.md"  # beside the scorecard folder: what the leaderboard shows, in words
CSV_FILE, FIGURE_FILE = "leaderboard.csv", "leaderboard.png"
CSV_HEAD = ["entry", "oracle", "subset", "controller", "source", "robots"]
SOFTWARE = "elastic-gym benchmark --leaderboard"


def default_outputs(page: str | Path) -> tuple[Path, Path]:
    """The CSV and the figure of a page: in the folder named like the page without
    ``.md`` (``docs/leaderboard/`` for ``docs/leaderboard.md``)."""
    page = Path(page)
    folder = page.with_suffix("")
    return folder / CSV_FILE, folder / FIGURE_FILE


def load_cards(folder: str | Path, suite: SuiteConfig) -> tuple[list[CheckedCard], list[str]]:
    """The checked cards of ``folder`` (by file name) and the notes of what was derived
    against a card's word; ``ValueError`` naming every refused card."""
    paths = sorted(Path(folder).glob("*.json"))
    if not paths:
        raise FileNotFoundError(f"no scorecard JSON file in {folder}")
    cards: list[CheckedCard] = []
    problems: list[str] = []
    labels: dict[str, Path] = {}
    for path in paths:
        try:
            checked = check_card(read_scorecard(path), suite, str(path))
        except ValueError as exc:
            problems.append(str(exc))
            continue
        if checked.label in labels:
            problems.append(
                f"{path}: entry.label {checked.label!r} is also the label of "
                f"{labels[checked.label]}"
            )
            continue
        labels[checked.label] = path
        cards.append(checked)
    if problems:
        count = f"{len(problems)} of {len(paths)} scorecards refused" if len(problems) > 1 else ""
        raise ValueError((count + ": " if count else "") + " | ".join(problems))
    return cards, [note for card in cards for note in card.notes]


def _columns(suite: SuiteConfig) -> list[str]:
    return [OVERALL, PRECISION, *suite.categories]


def _ordered(cards: Sequence[CheckedCard]) -> list[CheckedCard]:
    groups = tables(cards)
    return [*groups["implementable"], *groups["oracle"], *groups["subset"]]


def csv_text(cards: Sequence[CheckedCard], suite: SuiteConfig) -> str:
    """One row per card (implementable, oracle, subset; each ranked): what it is, its
    scores (4 decimals) and where it was measured."""
    columns = _columns(suite)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow([*CSV_HEAD, *columns, "package", "commit"])
    for checked in _ordered(cards):
        card = checked.card
        values = [score_value(card, c) for c in columns]
        writer.writerow(
            [
                card.label,
                checked.oracle,
                checked.subset,
                card.entry.controller,
                card.entry.source,
                " ".join(card.robots),
                *("" if v is None else f"{v:.4f}" for v in values),
                card.provenance.package,
                card.provenance.commit or "",
            ]
        )
    return buffer.getvalue()


def plot_leaderboard(cards: Sequence[CheckedCard], suite: SuiteConfig) -> bytes:
    """A heat map of entries (implementable, oracle, subset) x scores, as PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    columns = _columns(suite)
    ordered = _ordered(cards)
    data = np.array(
        [
            [math.nan if (v := score_value(c.card, k)) is None else v for k in columns]
            for c in ordered
        ]
    )
    fig, ax = plt.subplots(
        figsize=(0.8 * len(columns) + 3.2, 0.32 * len(ordered) + 1.4), constrained_layout=True
    )
    image = ax.imshow(data, cmap="viridis", vmin=0, vmax=1, aspect="auto")
    ax.set_xticks(range(len(columns)), columns, rotation=30, ha="right", fontsize=8)
    ax.set_yticks(range(len(ordered)), [plot_text(shown_label(c)) for c in ordered], fontsize=8)
    for i, row in enumerate(data):
        for j, value in enumerate(row):
            if math.isfinite(value):
                color = "white" if value < 0.6 else "black"
                ax.text(j, i, f"{value:.2f}", ha="center", va="center", fontsize=7, color=color)
    groups = tables(cards)
    edge = -0.5
    for name in ("implementable", "oracle"):  # a white line between the kinds of card
        edge += len(groups[name])
        if 0 < edge < len(ordered) - 0.5:
            ax.axhline(edge, color="white", linewidth=3)
    fig.colorbar(image, ax=ax, label="score", shrink=0.8)
    ax.set_title(f"{suite.name}: every score of every entry", fontsize=9)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100, metadata={"Software": SOFTWARE})
    plt.close(fig)
    return buffer.getvalue()


def written_here(path: Path) -> bool:
    """Whether ``path`` is a file an earlier rebuild wrote (page marker, CSV header,
    figure ``Software`` text)."""
    try:
        if path.suffix == ".png":
            from PIL import Image

            with Image.open(path) as image:
                return getattr(image, "text", {}).get("Software") == SOFTWARE
        with open(path, encoding="utf-8") as handle:
            first = handle.readline().rstrip("\n")
    except (OSError, ValueError):
        return False
    return first == MARKER or first.startswith(",".join(CSV_HEAD) + ",")


def check_targets(targets: Mapping[str, Path], scorecards: Path, overwrite: bool) -> None:
    """The rebuild's targets (option -> path) may be written: ``ValueError`` when two name
    one file or one is a scorecard file (``.json`` in the scorecard folder) or the notes
    (even with ``overwrite``),
    ``IsADirectoryError`` for a folder, ``FileExistsError`` naming the first target that is
    not a file an earlier rebuild wrote (unless ``overwrite``)."""
    seen: dict[Path, str] = {}
    for option, path in targets.items():
        resolved = path.resolve()
        if resolved in seen:
            raise ValueError(f"{seen[resolved]} and {option} name one file: {path}")
        seen[resolved] = option
        if resolved.parent == scorecards.resolve() and resolved.suffix == ".json":
            raise ValueError(
                f"{option} {path} is a scorecard file of {scorecards} (a .json there is a "
                "card): choose another path"
            )
        if resolved == (scorecards.parent / NOTES).resolve():
            raise ValueError(f"{option} {path} is the notes the page includes, not a target")
    for path in targets.values():
        if path.is_dir():
            raise IsADirectoryError(f"{path}: a folder, not a file the leaderboard can write")
        if path.exists() and not overwrite and not written_here(path):
            raise FileExistsError(
                f"{path}: exists and was not written by the leaderboard rebuild; choose "
                "another path or replace it with --overwrite"
            )


def rebuild_leaderboard(
    scorecards: str | Path = SCORECARD_DIR,
    page: str | Path = PAGE,
    suite: SuiteConfig | str | Path = DEFAULT_SUITE,
    csv_path: str | Path | None = None,
    figure: str | Path | None = None,
    overwrite: bool = False,
) -> tuple[list[Path], list[str]]:
    """Rebuild the page, CSV and figure from the scorecards (module docstring); return the
    files written and the notes of what was derived against a card's word. Nothing is
    written when a card is refused or a target may not be replaced."""
    if not isinstance(suite, SuiteConfig):
        suite = load_suite(suite)
    page = Path(page)
    default_csv, default_figure = default_outputs(page)
    csv_path = Path(csv_path) if csv_path is not None else default_csv
    figure = Path(figure) if figure is not None else default_figure
    cards, notes = load_cards(scorecards, suite)
    check_targets(
        {"--page": page, "--csv": csv_path, "--figure": figure}, Path(scorecards), overwrite
    )
    notes_file = Path(scorecards).parent / NOTES
    text = leaderboard_markdown(
        cards, suite, page, figure, notes_file.read_text() if notes_file.exists() else ""
    )
    outputs = {figure: plot_leaderboard(cards, suite), csv_path: csv_text(cards, suite).encode()}
    outputs[page] = text.encode()  # last: the page shows the others
    for path, data in outputs.items():
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.suffix == ".png":
            write_bytes(path, data)
        else:
            write_text(path, data.decode())
    return [page, csv_path, figure], notes
