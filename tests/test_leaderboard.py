"""The leaderboard checks what it ranks: every card validated, its scores recomputed from its
own episodes, its oracle flag derived, subset cards apart, labels escaped; the rebuild
writes only its three files, atomically, and replaces only files it wrote. No simulation:
the shipped cards are the data."""

from __future__ import annotations

import csv
import json
import math
import re
import shutil
from pathlib import Path

import jsonschema
import pytest
from helpers import ROOT

from elastic_gym.benchmark import load_suite, read_scorecard, rebuild_leaderboard
from elastic_gym.benchmark.audit import check_card
from elastic_gym.benchmark.card import METRICS, card_text, parse_scorecard
from elastic_gym.benchmark.command import entry_command, parse_command
from elastic_gym.benchmark.entry import Entry
from elastic_gym.benchmark.leaderboard import written_here
from elastic_gym.benchmark.markdown import code, plot_text, text
from elastic_gym.benchmark.scoring import compute_scores
from elastic_gym.benchmark.upgrade import upgrade_card
from elastic_gym.schemas import SCHEMA_DIR

SHIPPED = ROOT / "docs" / "leaderboard" / "scorecards"


def card_data(name: str) -> dict:
    return json.loads((SHIPPED / f"{name}.json").read_text())


@pytest.fixture(scope="module")
def suite():
    return load_suite()


@pytest.fixture
def board(tmp_path):
    """Three shipped cards in a scratch scorecard folder: implementable, oracle, subset."""
    folder = tmp_path / "docs" / "leaderboard" / "scorecards"
    folder.mkdir(parents=True)
    for name in ("eq13@deluca", "eq13@true", "ppo@deluca"):
        shutil.copy(SHIPPED / f"{name}.json", folder / f"{name}.json")
    return folder


def rebuild(folder: Path, **kwargs):
    page = folder.parent.parent / "leaderboard.md"
    return rebuild_leaderboard(folder, page, **kwargs)


def put(folder: Path, name: str, data: dict | str) -> Path:
    path = folder / f"{name}.json"
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return path


def outputs(folder: Path) -> list[Path]:
    docs = folder.parent.parent
    folder = docs / "leaderboard"
    return [docs / "leaderboard.md", folder / "leaderboard.csv", folder / "leaderboard.png"]


# ------------------------------------------------------------------ the shipped cards
@pytest.mark.slow
def test_every_shipped_card_validates_and_states_the_scores_its_episodes_give(suite):
    schema = json.loads((SCHEMA_DIR / "scorecard.json").read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    cards = sorted(SHIPPED.glob("*.json"))
    assert len(cards) >= 20
    for path in cards:
        data = json.loads(path.read_text())
        assert not list(jsonschema.Draft202012Validator(schema).iter_errors(data)), path
        card = read_scorecard(path)
        checked = check_card(card, suite, str(path))
        # recomputed bit for bit, not only within the tolerance
        assert checked.scores.overall == card.scores.overall, path
        assert checked.scores.passed == card.scores.passed
        assert card.command and parse_command(card.command).suite == suite.name
        assert "/work" not in path.read_text() and path.stat().st_size < 120_000


def test_compact_cards_keep_every_episode_once_in_columns(suite):
    card = read_scorecard(SHIPPED / "eq13@deluca.json")
    assert len(card.cells) == len(suite.cells) and card.seeds == list(suite.seeds)
    rows = list(card.episode_rows())
    assert len(rows) == len(suite.cells) * len(suite.seeds) == card.scores.episodes
    text_ = (SHIPPED / "eq13@deluca.json").read_text()
    assert text_.count('"track_rms"') == len(suite.cells)  # a key per cell, not per episode
    assert "sim_wall_ratio" not in text_ and "wall_time" in text_  # wall clock: provenance only
    assert card_text(card) == text_  # the file is the canonical text of its model


def test_a_format_1_card_upgrades_to_the_same_scores(suite):
    """A format 1 card built from a shipped card's episodes (keys repeated per episode)
    upgrades to a card equal to it in everything it holds."""
    new = card_data("eq13@deluca")
    old = {
        "format": 1,
        "suite": new["suite"],
        "package": {"version": "0.1.0", "commit": "abc"},
        "entry": new["entry"],
        "robots": new["robots"],
        "created": "2026-12-01T00:00:00Z",
        "wall_time": 1.0,
        "scores": new["scores"],
        "cells": [
            {
                "id": cell_id,
                "episodes": [
                    {
                        "seed": seed,
                        "status": columns["status"][i],
                        "passed": True,
                        "failed_checks": [],
                        "metrics": {
                            **{m: columns[m][i] for m in METRICS},
                            "sim_wall_ratio": 3.0,
                        },
                    }
                    for i, seed in enumerate(new["seeds"])
                ],
            }
            for cell_id, columns in new["cells"].items()
        ],
    }
    card = upgrade_card(old, suite)
    assert card.cells == parse_scorecard(new).cells and card.scores == parse_scorecard(new).scores
    assert card.command == new["command"] and card.provenance.commit == "abc"
    old["scores"]["overall"] = 0.9
    with pytest.raises(ValueError, match=r"scores.overall: the card states 0.9, its episodes give"):
        upgrade_card(old, suite)
    with pytest.raises(ValueError, match=r"format 1 .* --upgrade"):
        parse_scorecard(old)


# ------------------------------------------------------------------ cards refused
def refused(board: Path, data: dict | str, match: str) -> None:
    put(board, "hostile", data)
    with pytest.raises(ValueError, match=match) as info:
        rebuild(board)
    assert "hostile.json" in str(info.value)
    assert not any(p.exists() for p in outputs(board))  # nothing written


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("NaN", "Input should be a finite number"),
        ("Infinity", "a finite number"),
        ("5.0", "less than or equal to 1"),
        ("-0.1", "greater than or equal to 0"),
    ],
)
def test_an_overall_score_that_is_not_a_finite_share_is_refused(board, value, message):
    data = card_data("eq13@deluca")
    data["entry"]["label"] = "hostile"
    stated = f'"overall": {json.dumps(data["scores"]["overall"])}'
    text_ = json.dumps(data).replace(stated, f'"overall": {value}', 1)
    assert text_ != json.dumps(data)
    refused(board, text_, rf"scores\.overall: .*{message}")


def test_a_card_whose_episodes_all_failed_cannot_claim_a_high_score(board, suite):
    data = card_data("ppo@deluca")
    data["entry"]["label"] = "hostile"
    for columns in data["cells"].values():
        columns["status"] = ["failed: RuntimeError('boom')"] * len(columns["status"])
    data["scores"]["overall"] = 0.99
    refused(board, data, r"scores.overall: the card states 0.99, its episodes give 0\b")
    # the message names the first three differing fields and counts the others
    card = parse_scorecard(data)
    other = r"scores.categories.link-model: the card states 0.133333, its episodes give 0 "
    with pytest.raises(ValueError, match=other + r"\(and 6 more\)$"):
        check_card(card, suite)
    # the recomputed scores of such a card: 0 everywhere
    rescored = check_card(
        parse_scorecard({**data, "scores": _scores_of(card, suite)}), suite
    ).scores
    assert rescored.overall == 0.0 and rescored.passed == 0


def _scores_of(card, suite) -> dict:
    from elastic_gym.benchmark.audit import card_episodes

    scores = compute_scores(suite, card_episodes(card, suite))
    finite = lambda v: v if math.isfinite(v) else None  # noqa: E731
    return {
        "overall": scores.overall,
        "precision": scores.precision,
        "categories": {k: finite(v) for k, v in scores.categories.items()},
        "per_robot": {r: {k: finite(v) for k, v in d.items()} for r, d in scores.per_robot.items()},
        "episodes": scores.episodes,
        "passed": scores.passed,
    }


def test_an_edited_metric_changes_what_its_episodes_give_and_is_refused(board):
    data = card_data("eq13@deluca")
    data["entry"]["label"] = "hostile"
    data["cells"]["two-link/nominal/smooth"]["track_rms"][0] = 0.5  # fails 5e-4 now
    stated = re.escape(f"{data['scores']['overall']:.6g}")
    refused(board, data, rf"scores.overall: the card states {stated}, its episodes give 0.61")


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.update(format=99), r"format: Input should be 2"),
        (lambda d: d.update(cells={}), r"cells: Dictionary should have at least 1 item"),
        (
            lambda d: d["cells"]["kr15/nominal/fast"].update(status=[]),
            r"cells.kr15/nominal/fast.status: 0 values for the card's 10 seeds",
        ),
        (
            lambda d: d["cells"].pop("kr15/latency/actuator-delay-2"),
            r"cells: 1 of the suite's 56 cells of robots \['two-link', 'kr15'\] missing: "
            r"\['kr15/latency/actuator-delay-2'\]",
        ),
        (
            lambda d: d["cells"].update({"kr15/latency/delay-9": d["cells"]["kr15/nominal/fast"]}),
            r"cells: unknown cell\(s\) \['kr15/latency/delay-9'\]",
        ),
        (
            lambda d: d["scores"]["categories"].pop("friction"),
            r"scores.categories: missing \['friction'\]",
        ),
        (
            lambda d: d["scores"]["categories"].update(luck=1.0),
            r"scores.categories: unknown \['luck'\]; valid: \['nominal'",
        ),
        (lambda d: d["scores"].update(passed=600), r"passed \(600\) exceeds episodes \(560\)"),
        (lambda d: d.update(seeds=list(range(10))), r"seeds: \[0, 1, 2, 3, 4, \.\.\.\] are not"),
        (lambda d: d["suite"].update(version=1), r"not of elastic-gym-v2 version 2"),
        (lambda d: d["suite"].update(hash="0" * 64), r"\(the suite changed\)"),
        (lambda d: d["entry"].update(label="x" * 101), r"entry.label: the label is 101 char"),
        (lambda d: d.update(extra=1), r"extra: unexpected field"),
        (lambda d: d["entry"].update(source="nope"), r"entry.source: unknown state source"),
    ],
)
def test_malformed_cards_are_refused_naming_the_card_and_field(board, change, message):
    data = card_data("eq13@deluca")
    data["entry"]["label"] = "hostile"
    change(data)
    refused(board, data, message)


def test_an_oracle_relabelled_as_an_observer_contradicts_its_own_command(board):
    """The true state's episodes under ``source: deluca``: its command still says
    ``--source true``; a card whose entry is not the one its command scores is refused."""
    data = card_data("eq13@true")
    data["entry"].update(label="hostile", source="deluca", privileged=[], oracle=False)
    refused(board, data, r"entry.source: 'deluca', but the card's command names --source 'true'")
    data = card_data("eq13@deluca")
    data["entry"].update(label="hostile", controller="link-pd")
    message = r"entry.controller: 'link-pd', but the card's command names --controller 'feedf"
    refused(board, data, message)
    data = card_data("eq13@deluca")
    data["entry"].update(label="hostile", controller_options={"gain": 2})
    refused(board, data, r"entry.controller_options: \{'gain': 2\}, but the card's command")
    data = card_data("eq13@deluca")
    data.update(command=data["command"].replace("--source deluca", "--source ekf"))
    data["entry"]["label"] = "hostile"
    refused(board, data, r"entry.source: 'deluca', but the card's command names --source 'ekf'")
    data = card_data("eq13@deluca")
    data["entry"].update(label="hostile", models=["kr15.yaml"])
    refused(
        board, data, r"entry.models: \['kr15.yaml'\], but the card's command names --model \[\]"
    )
    data = card_data("ppo@deluca")
    data["entry"]["label"] = "hostile"
    data["entry"]["controller_options"]["policy"] = "docs/leaderboard/runs/rppo@sensors"
    message = r"entry.controller_options.policy: 'docs/leaderboard/runs/rppo@sensors', but the"
    refused(board, data, message + r" card's command names --run 'docs/leaderboard/runs/ppo@")
    data = card_data("eq13@deluca")
    data.update(command=data["command"] + " --suite elastic-gym-v9")
    data["entry"]["label"] = "hostile"
    refused(board, data, r"suite: elastic-gym-v2, but the card's command names --suite 'elastic")


def test_two_cards_with_one_label_and_non_json_files_are_refused(board):
    data = card_data("eq13@deluca")
    refused(board, data, r"entry.label 'eq13@deluca' is also the label of .*eq13@deluca.json")
    refused(board, "{not json", "not a scorecard JSON file")
    refused(board, "[1, 2]", "not a scorecard")


# ------------------------------------------------------------------ what a card is
HOSTILE = "x|y\n<script>alert(1)</script> *b* [l](http://e) `c` $\\alpha$"


@pytest.fixture(scope="module")
def built(tmp_path_factory, suite):
    """One rebuild of: eq13@deluca, eq13@true, ppo@deluca (two-link only), eq13@true
    relabelled ``oracle: false`` ("sneaky"), eq13@deluca cut to the two-link arm with its
    scores recomputed ("cut") and eq13@deluca under a hostile label."""
    folder = tmp_path_factory.mktemp("built") / "docs" / "leaderboard" / "scorecards"
    folder.mkdir(parents=True)
    for name in ("eq13@deluca", "eq13@true", "ppo@deluca"):
        shutil.copy(SHIPPED / f"{name}.json", folder / f"{name}.json")
    sneaky = card_data("eq13@true")
    sneaky["entry"].update(label="sneaky", oracle=False, privileged=[])
    put(folder, "sneaky", sneaky)
    cut = card_data("eq13@deluca")
    cut["entry"]["label"] = "cut"
    cut["robots"] = ["two-link"]
    cut["cells"] = {k: v for k, v in cut["cells"].items() if k.startswith("two-link/")}
    cut["scores"]["per_robot"] = {"two-link": cut["scores"]["per_robot"]["two-link"]}
    with pytest.raises(ValueError, match=r"stated scores differ.*scores.overall: the card states"):
        check_card(parse_scorecard(cut), suite)  # all-robot scores are not one robot's
    put(folder, "cut", {**cut, "scores": _scores_of(parse_scorecard(cut), suite)})
    hostile = card_data("eq13@deluca")
    hostile["entry"]["label"] = HOSTILE
    put(folder, "hostile", hostile)
    files, notes = rebuild(folder)
    page = files[0].read_text()
    with open(files[1], newline="") as handle:
        rows = list(csv.DictReader(handle))
    return page, rows, notes


def section(page: str, title: str) -> str:
    return page.split(f"## {title}")[1].split("\n## ")[0]


def test_an_oracle_relabelled_implementable_still_goes_to_the_oracle_table(built):
    page, rows, notes = built
    assert "sneaky" not in section(page, "Implementable entries")
    assert "[sneaky](#entry-sneaky)" in section(page, "Oracle references")
    assert any("sneaky.json: states oracle: false, but its source 'true' reads" in n for n in notes)
    assert {r["entry"]: r["oracle"] for r in rows}["sneaky"] == "True"


def test_a_subset_card_is_not_ranked_with_the_full_ones(built):
    page, rows, _ = built
    ranked = page.split("## Scored on part of the suite")[0]
    subset = section(page, "Scored on part of the suite")
    assert "[ppo@deluca]" not in ranked and "[cut]" not in ranked
    assert "| 1 | [cut](#entry-cut) | two-link |" in subset
    assert "| 2 | [ppo@deluca](#entry-ppo-deluca) | two-link |" in subset
    assert [(r["entry"], r["subset"]) for r in rows][-2:] == [
        ("cut", "True"),
        ("ppo@deluca", "True"),
    ]


def test_a_hostile_label_never_reaches_the_page_raw(built):
    page, rows, _ = built
    assert "<script" not in page and "alert(1)</" not in page
    assert "](http://e)" not in page and "*b*" not in page
    tables = [ln for ln in page.splitlines() if "](#entry-hostile) |" in ln]
    assert tables and tables[0].count("|") == 6  # | # | entry | source | overall | precision |
    assert text(HOSTILE) in page
    assert "\n" not in text(HOSTILE) and "|" not in text(HOSTILE).replace("&#124;", "")
    assert code("a`b|c") == "<code>a`b&#124;c</code>" and code("a|b").startswith("<code>")
    assert "$" not in plot_text("$x$").replace("\\$", "") and len(plot_text("y" * 99)) == 40
    assert HOSTILE in [r["entry"] for r in rows]  # the CSV keeps it, quoted


def test_table_rows_have_their_headers_cell_count_and_at_most_six_columns(built):
    page, _, _ = built
    lines = [ln.strip() for ln in page.splitlines()]
    tables = 0
    for i, line in enumerate(lines):
        if line.startswith("|---"):
            tables += 1
            width = lines[i - 1].count("|")
            assert width <= 7, lines[i - 1]  # at most six columns
            j = i + 1
            while j < len(lines) and lines[j].startswith("|"):
                assert lines[j].count("|") == width, lines[j]
                j += 1
    assert tables >= 3 + 6 + 5  # short tables, one per entry, one per task
    figure = page.index("![scores of every entry](leaderboard/leaderboard.png)")
    assert figure < page.index("## Implementable entries") < page.index("## Per entry")
    assert "commit" not in page[: page.index("## Per entry")]


# ------------------------------------------------------------------ what the rebuild writes
def test_the_rebuild_writes_three_files_where_it_is_told_and_nowhere_else(tmp_path, board):
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    page, table, figure = tmp_path / "p" / "board.md", tmp_path / "t.csv", tmp_path / "f.png"
    files, _ = rebuild_leaderboard(board, page, csv_path=table, figure=figure)
    assert files == [page, table, figure]
    after = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    new = sorted(set(after) - set(before))
    assert new == sorted(p.relative_to(tmp_path) for p in [page.parent, page, table, figure])
    assert "![scores of every entry](../f.png)" in page.read_text()
    assert all(written_here(p) for p in files)
    # the defaults: beside the page, in the folder named like it
    files, _ = rebuild_leaderboard(board, tmp_path / "site" / "lb.md")
    assert [f.relative_to(tmp_path).as_posix() for f in files] == [
        "site/lb.md",
        "site/lb/leaderboard.csv",
        "site/lb/leaderboard.png",
    ]


def test_a_file_the_rebuild_did_not_write_is_replaced_only_with_overwrite(board):
    targets = outputs(board)
    targets[1].parent.mkdir(parents=True, exist_ok=True)
    for target in targets:
        target.write_bytes(b"my own notes\n")
    for i, target in enumerate(targets):
        with pytest.raises(FileExistsError, match=f"{target.name}: exists and was not written by"):
            rebuild(board)
        assert [t.read_bytes() == b"my own notes\n" for t in targets[i:]] == [True] * (3 - i)
        target.unlink()  # the next one is named next
        assert not any(written_here(t) for t in targets)
    for target in targets:
        target.write_bytes(b"my own notes\n")
    rebuild(board, overwrite=True)
    assert all(written_here(t) for t in targets)
    rebuild(board)  # its own files: replaced without --overwrite


def test_targets_that_are_one_file_or_a_card_are_refused_even_with_overwrite(board):
    page = board.parent / "lb.md"
    card = board / "eq13@deluca.json"
    kept = card.read_bytes()
    notes = board.parent / "notes.md"
    notes.write_text("What the leaderboard shows.\n")
    for kwargs, message in [
        ({"csv_path": page}, r"--page and --csv name one file: .*lb\.md"),
        ({"csv_path": board.parent / "x.png"}, r"--csv and --figure name one file"),
        ({"csv_path": card}, r"--csv .*eq13@deluca\.json is a scorecard file of"),
        ({"figure": board / "f.json"}, r"--figure .*f\.json is a scorecard file of"),
        ({"csv_path": board.parent / "notes.md"}, r"--csv .*notes\.md is the notes the page"),
    ]:
        figure = kwargs.pop("figure", board.parent / "x.png")
        with pytest.raises(ValueError, match=message):
            rebuild_leaderboard(board, page, figure=figure, overwrite=True, **kwargs)
        assert not page.exists() and card.read_bytes() == kept
        assert notes.read_text() == "What the leaderboard shows.\n"
    notes.unlink()


@pytest.mark.slow
def test_the_cli_rebuild_refuses_and_names_the_file(board, capsys):
    from elastic_gym.cli import main

    page = board.parent.parent / "leaderboard.md"
    page.write_text("# mine\n")
    args = ["benchmark", "--leaderboard", "--scorecards", str(board), "--page", str(page)]
    with pytest.raises(SystemExit) as stopped:
        main(args)
    assert stopped.value.code == 2
    assert "leaderboard.md: exists and was not written by the leaderboard rebuild" in (
        capsys.readouterr().err
    )
    assert main([*args, "--overwrite"]) == 0
    assert "written: " in capsys.readouterr().out


# ------------------------------------------------------------------ commands
def test_an_entry_command_reads_back_to_the_same_entry():
    entry = Entry(
        controller="integral-state-feedback",
        source="deluca",
        options={"load_identification": "shared", "gain": 1e-05, "n": [1, 2]},
        source_options={"omega": 250.0},
        label="it's a label",
    )
    command = entry_command(entry, "elastic-gym-v1", ["two-link"])
    back = parse_command(command)
    assert back.suite == "elastic-gym-v1" and back.robots == ["two-link"]
    assert Entry(**back.entry) == entry
    assert entry_command(Entry(controller="policy", options={"policy": len}), "s") is None
    for bad, message in [
        ("python -c 1", "not an `elastic-gym benchmark` command"),
        ("elastic-gym benchmark --controller motor-pd --sorce x --suite s", "unrecognized"),
        ("elastic-gym benchmark --controller motor-pd", "names no --suite"),
        ("elastic-gym benchmark --leaderboard --suite s", "unrecognized arguments"),
    ]:
        with pytest.raises(ValueError, match=message):
            parse_command(bad)


def test_a_run_entry_is_recorded_by_the_path_it_was_given(monkeypatch):
    """The card names the run folder as the command does (no machine's absolute path);
    the controller gets it resolved (workers may start elsewhere)."""
    from elastic_gym.benchmark.entry import describe_entry, resolve_entry

    monkeypatch.chdir(ROOT)
    given = "docs/leaderboard/runs/ppo@deluca"  # an exported policy: no pickle, no trust
    record = describe_entry(Entry(run=given))
    assert record["controller_options"]["policy"] == given
    assert record["run"]["exported"] and record["run"]["algo"] == "ppo"
    controller, _ = resolve_entry(Entry(run=given))
    assert controller.options["policy"] == str(ROOT / given)


def test_a_rerun_one_ulp_off_in_one_episode_is_named_and_only_it():
    """`--verify` compares a card with its re-run bit for bit: a card equals itself, and
    one episode's value moved by one unit in the last place is the one difference."""
    from elastic_gym.benchmark.verify import card_differences, same_bits

    card = read_scorecard(sorted(SHIPPED.glob("*.json"))[0])
    itself = card_differences(card, card)
    assert itself.compared > len(card.seeds) and itself.differences == []
    data = card.model_dump(mode="json")
    cell_id, columns = next(iter(data["cells"].items()))
    value = columns["track_rms"][0]
    columns["track_rms"][0] = math.nextafter(value, math.inf)
    found = card_differences(card, type(card).model_validate(data))
    assert found.compared == itself.compared
    assert found.differences == [
        f"cells.{cell_id}.track_rms[seed {card.seeds[0]}]: card {value!r}, "
        f"re-run {math.nextafter(value, math.inf)!r}"
    ]
    assert found.only_metrics and found.score_difference == 0.0
    assert same_bits(math.nan, math.nan) and not same_bits(0.0, -0.0)
    assert not same_bits(None, 0.0) and same_bits(None, None)


@pytest.mark.parametrize(
    ("change", "reproduced"),
    [
        ("scores within the tolerance", True),
        ("a metric null on one side", True),
        ("a score beyond the tolerance", False),
        ("a status", False),
        ("a count of passed episodes", False),
    ],
)
def test_another_machine_reproduces_a_card_only_within_its_scores_tolerance(change, reproduced):
    """On another CPU the floats' last bits differ: a re-run that differs in episodes'
    metrics (one may be null on one side) and scores, whose statuses are the card's and
    whose scores are within `SCORE_TOLERANCE`, reproduces it, not bit for bit; a status,
    a count or a score further off does not."""
    from elastic_gym.benchmark.verify import SCORE_TOLERANCE, Verification, card_differences

    card = read_scorecard(sorted(SHIPPED.glob("*.json"))[0])
    data = card.model_dump(mode="json")
    cell_id, columns = next(iter(data["cells"].items()))
    columns["track_rms"][0] *= 1.1  # a sensitive episode's metric, well off
    scores = data["scores"]
    if change == "scores within the tolerance":
        scores["overall"] += SCORE_TOLERANCE / 2
    elif change == "a metric null on one side":  # settled at the window's end, or not
        settled = columns["settling_time"]
        settled[1] = None if settled[1] is not None else 0.5
    elif change == "a score beyond the tolerance":
        scores["precision"] -= 2 * SCORE_TOLERANCE
    elif change == "a status":
        columns["status"][0] += "-not"
    else:
        scores["passed"] += 1
    found = card_differences(card, type(card).model_validate(data))
    verdict = Verification(card=Path("card.json"), rerun=card, **vars(found))
    assert not verdict.exact and verdict.reproduced is reproduced
    expected = (
        "reproduced within 0.001 of every score, not bit for bit"
        if reproduced
        else "NOT reproduced"
    )
    assert verdict.text().startswith(f"card.json: {expected}")
