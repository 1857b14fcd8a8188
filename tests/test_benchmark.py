"""The benchmark: suite validation and hash, scoring math, entries, scorecards, leaderboard."""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers import cli_exit_code, tiny_suite_data
from helpers import shipped_suite_data as shipped_data

from elastic_gym.benchmark import load_suite, read_scorecard, rebuild_leaderboard, run_benchmark
from elastic_gym.benchmark.card import METRICS
from elastic_gym.benchmark.entry import Entry, describe_entry, resolve_entry
from elastic_gym.benchmark.run import records
from elastic_gym.benchmark.scoring import (
    Episode,
    _number,
    compute_scores,
    episode_checks,
    precision_value,
    score_episodes,
)
from elastic_gym.benchmark.suite import SUITE_DIR, SuiteConfig, canonical_form, suite_scenario
from elastic_gym.evaluation import plan_runs, run_episode
from elastic_gym.evaluation.metrics import TimeSeries, compute_metrics
from elastic_gym.validation import validated

SHIPPED = SUITE_DIR / "elastic-gym-v1.yaml"


# ---------------------------------------------------------------- suite
def test_shipped_suite_validates_and_its_hash_is_the_sha256_of_the_canonical_form():
    suite = load_suite(SHIPPED)
    assert suite.name == "elastic-gym-v1" and suite.version == 1
    assert load_suite().name == "elastic-gym-v2"  # the default: v1 on the converged RK4
    assert len(suite.seeds) >= 10 and suite.physics_dt == 6.25e-5
    assert suite.hash == hashlib.sha256(canonical_form(suite).encode()).hexdigest()
    per_robot = sum(len(c.cells) for c in suite.categories.values())
    assert len(suite.cells) == per_robot * len(suite.robots)
    # comments, key order and number spelling do not change the hash; a tolerance does
    data = shipped_data()
    reordered = dict(reversed(list(data.items())))
    reordered["tasks"]["smooth"]["tolerance"]["track_rms"] = 0.0005
    assert validated(SuiteConfig, reordered).hash == suite.hash
    changed = copy.deepcopy(data)
    changed["tasks"]["smooth"]["tolerance"]["track_rms"] = 6e-4
    assert validated(SuiteConfig, changed).hash != suite.hash


def test_cells_merge_robot_task_and_perturbation_kwargs():
    suite = load_suite()
    cell = next(c for c in suite.cells if c.id == "kr15/nominal/fast")
    assert cell.kwargs["task_options"] == {
        "n_moves": 2,
        "dwell_time": 0.1,
        "move_time": 0.3,
        "max_move": 0.6,
    }
    cell = next(c for c in suite.cells if c.id == "two-link/link-model/mass+10%")
    assert cell.kwargs["plant_scaling"] == {"link_mass": 1.1}
    assert cell.kwargs["task"] == "tracking" and cell.tolerance.limits() == {
        "track_rms": 5e-4,
        "track_max": 1.5e-3,
    }


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            lambda d: d["categories"]["nominal"]["cells"][0].update(taks="x"),
            "categories.nominal.cells[0].taks: unexpected field",
        ),
        (
            lambda d: d["categories"]["nominal"]["cells"][0].update(task="nope"),
            "categories.nominal.cells[0].task: unknown task 'nope'",
        ),
        (lambda d: d.update(seeds=list(range(9))), "seeds: List should have at least 10"),
        (lambda d: d.update(seeds=[1] * 10), "seeds: duplicate seed(s) [1]"),
        (
            lambda d: d["tasks"]["smooth"]["tolerance"].update(track_rms=-1),
            "tasks.smooth.tolerance.track_rms: Input should be greater than 0",
        ),
        (
            lambda d: d["categories"]["friction"]["cells"][0]["plant"].update(frictionn=1),
            "unknown env kwarg(s) ['frictionn']",
        ),
        (
            lambda d: d["robots"]["kr15"].update(env="Nope-v0"),
            "robots.kr15.env: unknown env id",
        ),
        (lambda d: d.update(physics_dt=2e-3), "physics_dt: Input should be less than or equal"),
        (lambda d: d["precision"].update(low=1.0), "low (1) must be < high (0.1)"),
        (
            lambda d: [c.update(weight=0) for c in [*d["categories"].values(), d["precision"]]],
            "categories: every weight is 0",
        ),
    ],
)
def test_bad_suites_are_refused_naming_the_field(change, message):
    data = shipped_data()
    change(data)
    with pytest.raises(ValueError) as info:
        validated(SuiteConfig, data)
    assert message in str(info.value)


def test_a_suite_file_with_every_weight_zero_is_refused_at_load_naming_the_file(tmp_path):
    data = shipped_data()
    for category in [*data["categories"].values(), data["precision"]]:
        category["weight"] = 0
    path = tmp_path / "zero.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ValueError) as info:
        load_suite(path)
    message = str(info.value)
    assert message.startswith(f"{path}: categories: every weight is 0")
    assert "got None" not in message and "\n" not in message
    # one positive weight is enough (the overall score is then that score)
    data["precision"]["weight"] = 0.5
    path.write_text(yaml.safe_dump(data))
    assert load_suite(path).precision.weight == 0.5


# ---------------------------------------------------------------- scoring
def test_run_records_are_the_rows_as_one_table_as_pandas_gives_them():
    """The scoring gets every column of any row, in first-seen order, NaN where a row has
    none: the records pandas made of the comparison's rows before (no pandas needed)."""
    pandas = pytest.importorskip("pandas")
    rows = [
        {"env": "a", "seed": 1, "status": "ok", "rms": 1.5, "jumps": 3},
        {"env": "b", "seed": 2, "status": "failed: ValueError: x", "cond": np.float64(2.0)},
        {"env": "c", "seed": 3, "status": "ok", "rms": None, "jumps": True},
    ]
    ours, theirs = records(rows), pandas.DataFrame(rows).to_dict("records")
    assert [list(r) for r in ours] == [list(r) for r in theirs]
    assert list(ours[1]) == ["env", "seed", "status", "rms", "jumps", "cond"]
    assert math.isnan(ours[1]["rms"]) and math.isnan(ours[0]["cond"])
    for mine, pandas_row in zip(ours, theirs, strict=True):  # the numbers the scoring reads
        assert str(_as_scored(mine)) == str(_as_scored(pandas_row))


def _as_scored(row: dict) -> list:
    return [row[k] if k in ("env", "status") else _number(row[k]) for k in row]


def test_precision_map_is_log_linear_and_monotone():
    assert precision_value(1e-6, 1e-6, 1e-1) == 1.0
    assert precision_value(1e-9, 1e-6, 1e-1) == 1.0
    assert precision_value(1e-1, 1e-6, 1e-1) == 0.0
    assert precision_value(3.0, 1e-6, 1e-1) == 0.0
    for decade in range(6):
        assert precision_value(10.0 ** (-1 - decade), 1e-6, 1e-1) == pytest.approx(
            decade / 5, abs=1e-12
        )
    values = [precision_value(r, 1e-6, 1e-1) for r in np.geomspace(1e-7, 1.0, 50)]
    assert all(a >= b for a, b in itertools.pairwise(values))
    assert precision_value(math.nan, 1e-6, 1e-1) == 0.0
    assert precision_value(math.inf, 1e-6, 1e-1) == 0.0


def test_category_precision_and_overall_scores_are_the_documented_means():
    suite = validated(SuiteConfig, tiny_suite_data())
    nominal, latency, _ = (c for c in suite.cells)
    episodes = []
    for i, seed in enumerate(suite.seeds):
        rms = 10.0 ** (-2 - i % 3)  # 1e-2 and 1e-3 fail the 5e-4 threshold, 1e-4 passes
        metrics = {"track_rms": rms, "track_max": 1e-3}
        episodes.append(
            Episode(nominal.id, seed, "ok", metrics, episode_checks(nominal, "ok", metrics))
        )
        status = "ok" if i < 3 else "terminated: non-finite state"
        episodes.append(
            Episode(latency.id, seed, status, metrics, episode_checks(latency, status, metrics))
        )
    scores = compute_scores(suite, episodes)
    rms = [10.0 ** (-2 - i % 3) for i in range(10)]
    assert scores.categories["nominal"] == sum(r <= 5e-4 for r in rms) / 10 == 0.3
    assert scores.categories["latency"] == sum(r <= 5e-4 for r in rms[:3]) / 10 == 0.1
    expected_precision = np.mean([math.log(1e-1 / r) / math.log(1e5) for r in rms])
    assert scores.precision == pytest.approx(expected_precision, abs=1e-12)
    assert math.isnan(scores.categories["link-model"])  # no episode: left out of the mean
    weights = {"nominal": 1.0, "latency": 1.0, "precision": 1.0}
    values = {**scores.categories, "precision": scores.precision}
    overall = sum(weights[k] * values[k] for k in weights) / sum(weights.values())
    assert scores.overall == pytest.approx(overall, abs=1e-15)
    assert scores.per_robot["two-link"]["overall"] == scores.overall
    # a missing metric or a NaN fails its check; a failed run fails "status"
    assert episode_checks(nominal, "ok", {"track_rms": math.nan, "track_max": 0.0}) == (
        "track_rms > 0.0005",
    )
    assert episode_checks(nominal, "failed: X", {"track_rms": 0.0})[0] == "status"


def test_torque_rate_and_saturation_share_metrics():
    t = np.arange(5) * 1e-3
    torque = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 2.0], [1.0, 2.0], [0.0, 0.0]])
    zeros = np.zeros((5, 2))
    saturated = np.array([False, True, True, False, False])
    error = np.zeros((5, 4))
    series = TimeSeries(t, zeros, zeros, zeros, torque, error, ("q", "dq"), saturated=saturated)
    metrics = compute_metrics(series)
    rates = np.array([1.0, 2.0, 0.0, math.sqrt(5.0)]) / 1e-3
    assert metrics["torque_rate_rms"] == pytest.approx(math.sqrt(np.mean(rates**2)), rel=1e-14)
    assert metrics["saturation_share"] == 0.4


# ---------------------------------------------------------------- entries
def test_entries_record_what_they_read_and_oracles_are_marked():
    assert (
        describe_entry(Entry(controller="motor-pd", source="finite-difference"))["oracle"] is False
    )
    truth = describe_entry(Entry(controller="motor-pd", source="true"))
    assert truth["oracle"] is True and truth["privileged"] == ["true_state"]
    ideal = describe_entry(Entry(controller="feedforward-state-feedback", source="deluca-ideal"))
    assert ideal["privileged"] == ["link_acceleration"]
    user = describe_entry(
        Entry(
            controller="elastic_gym.controllers.pd:LinkPD",
            source="elastic_gym.observers.ekf:ExtendedKalmanFilter",
            options={"omega": 20.0},
        )
    )
    assert user["controller"] == "elastic_gym.controllers.pd:LinkPD" and not user["oracle"]
    assert user["controller_options"] == {"omega": 20.0}
    for fields, message in [
        ({"controller": "nope"}, "controller: unknown controller 'nope'"),
        ({"controller": "motor-pd", "source": "nope"}, "source: unknown state source 'nope'"),
        (
            {"controller": "motor-pd", "run": "x"},
            "give one of controller or run, not controller and run",
        ),
        ({"controller": "motor-pd", "sorce": "x"}, "entry.sorce: unexpected field"),
        ({"run": "/nonexistent"}, "run: /nonexistent is neither an exported policy"),
    ]:
        with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
            resolve_entry(validated(Entry, fields, prefix="entry"))


# ---------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def tiny_cards(tmp_path_factory):
    """Two entries scored on the tiny suite, in this process."""
    root = tmp_path_factory.mktemp("bench")
    suite_file = root / "tiny.yaml"
    suite_file.write_text(yaml.safe_dump(tiny_suite_data()))
    cards = {}
    for label, entry in {
        "eq13@deluca": {"controller": "feedforward-state-feedback", "source": "deluca"},
        "eq13@true": {"controller": "feedforward-state-feedback", "source": "true"},
    }.items():
        cards[label] = run_benchmark(
            {**entry, "label": label},
            suite=suite_file,
            output_dir=root / label,
            workers=1,
            progress=False,
            figure=label == "eq13@true",
        )
    return root, suite_file, cards


@pytest.mark.slow
def test_scorecard_holds_the_comparisons_episodes_bit_for_bit(tiny_cards):
    root, suite_file, cards = tiny_cards
    suite = load_suite(suite_file)
    card = cards["eq13@deluca"]
    controller, source = resolve_entry(
        Entry(controller="feedforward-state-feedback", source="deluca")
    )
    runs, _ = plan_runs(suite_scenario(suite, controller, source))
    assert len(runs) == len(suite.cells) * len(suite.seeds) == card.scores.episodes
    spec = runs[len(suite.seeds) + 3]  # latency cell, fourth seed
    # the mass cell shares the nominal cell's world (per-arm plants) and is scored too
    assert "two-link/link-model/m" in card.cells
    direct = run_episode(spec)
    status, metrics = next(
        (status, metrics)
        for cell_id, seed, status, metrics in card.episode_rows()
        if cell_id == spec.labels["env"] and seed == spec.seed
    )
    assert status == direct.status
    for key in METRICS:  # every metric the card keeps, bit for bit
        assert metrics[key] == direct.metrics[key] or (
            math.isnan(metrics[key]) and not math.isfinite(direct.metrics[key])
        )
    # the scores are the scoring of those episodes, and the JSON file reads back equal
    rows = [
        {"env": cell_id, "seed": seed, "status": status, **metrics}
        for cell_id, seed, status, metrics in card.episode_rows()
    ]
    rescored = compute_scores(suite, score_episodes(suite, rows))
    assert rescored.overall == card.scores.overall
    assert read_scorecard(root / "eq13@deluca" / "scorecard.json") == card
    assert card.suite.hash == suite.hash and card.entry.oracle is False
    assert card.command == (
        "elastic-gym benchmark --controller feedforward-state-feedback --source deluca "
        f"--label eq13@deluca --suite {suite_file}"
    )
    assert (root / "eq13@true" / "scores.png").stat().st_size > 1000


@pytest.mark.slow
def test_two_control_periods_of_sensor_delay_break_the_observer_loop_not_the_oracle(tiny_cards):
    _, _, cards = tiny_cards
    observed, oracle = cards["eq13@deluca"], cards["eq13@true"]
    assert oracle.scores.categories["nominal"] == 1.0
    # the delayed estimate ruins eq. (13) on the De Luca observer within 0.1 s
    assert observed.scores.categories["latency"] < oracle.scores.categories["latency"]


@pytest.mark.slow
def test_leaderboard_rebuilds_from_scorecards_and_refuses_other_suites(tiny_cards, tmp_path):
    root, suite_file, cards = tiny_cards
    folder = tmp_path / "scorecards"
    folder.mkdir()
    for label in cards:
        (folder / f"{label}.json").write_text((root / label / "scorecard.json").read_text())
    page = tmp_path / "leaderboard.md"
    files, _ = rebuild_leaderboard(folder, page, suite_file)
    text = page.read_text()
    implementable, oracle = text.split("## Oracle references")
    assert "eq13@deluca" in implementable.split("## Implementable entries")[1]
    assert "eq13@true" in oracle.split("## Per entry")[0]
    assert all(Path(f).exists() for f in files)
    data = json.loads((folder / "eq13@true.json").read_text())
    data["suite"]["version"] = 2
    (folder / "eq13@true.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="not of elastic-gym-v1 version 1 "):
        rebuild_leaderboard(folder, page, suite_file)
    data["suite"]["version"], data["suite"]["hash"] = 1, "0" * 64
    (folder / "eq13@true.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="the suite changed"):
        rebuild_leaderboard(folder, page, suite_file)
    assert cli_exit_code(["benchmark", "--leaderboard", "--scorecards", str(folder)]) == 2


@pytest.mark.slow
def test_a_card_of_30_failed_episodes_claiming_099_is_refused(tiny_cards, tmp_path):
    """The issue's case on a real card: the tiny suite's 3 cells x 10 seeds, every episode
    edited to a failure, the scores left as stated (and overall raised to 0.99)."""
    root, suite_file, _ = tiny_cards
    data = json.loads((root / "eq13@deluca" / "scorecard.json").read_text())
    statuses = [s for cell in data["cells"].values() for s in cell["status"]]
    assert len(statuses) == 30
    for cell in data["cells"].values():
        cell["status"] = ["failed: RuntimeError: edited"] * len(cell["status"])
    data["scores"]["overall"] = 0.99
    folder = tmp_path / "scorecards"
    folder.mkdir()
    (folder / "claims.json").write_text(json.dumps(data))
    page = tmp_path / "leaderboard.md"
    with pytest.raises(
        ValueError,
        match=r"claims.json: stated scores differ .*scores.overall: "
        r"the card states 0.99, its episodes give 0;",
    ):
        rebuild_leaderboard(folder, page, suite_file)
    assert not page.exists()


@pytest.mark.slow
def test_cli_scores_a_users_class_and_refuses_bad_combinations(tiny_cards, tmp_path, capsys):
    _, suite_file, _ = tiny_cards
    observer = "elastic_gym.observers.finite_difference:FiniteDifferenceObserver"
    args = ["benchmark", "--suite", str(suite_file), "--workers", "1", "--no-progress"]
    code = cli_exit_code(
        [*args, "--class", observer, "--controller", "motor-pd", "--output", str(tmp_path / "a")]
    )
    assert code == 0
    card = read_scorecard(tmp_path / "a" / "scorecard.json")
    assert card.entry.source == observer and card.entry.controller == "motor-pd"
    assert re.search(r"30 runs .*on 1 worker, about \d+ s", capsys.readouterr().out)
    for bad, message in [
        (["--class", observer, "--source", "ekf"], "--class (an Observer) and --source"),
        (
            ["--class", "elastic_gym.controllers.pd:MotorPD", "--controller", "motor-pd"],
            "--class (a Controller) and --controller",
        ),
        (
            ["--class", "elastic_gym.envs:ElasticArmEnv"],
            "neither a subclass of Controller nor Observer",
        ),
        (["--controller", "motor-pd", "--output", str(tmp_path / "a")], "holds an earlier result"),
        (["--controller", "motor-pd", "--robot", "kr15"], "unknown robot(s) ['kr15']"),
        (
            ["--controller", "motor-pd", "--label", "x" * 300],
            "entry.label: the label is 300 characters long, more than 100 (it starts 'xxx",
        ),
        ([], "give one of --leaderboard or --verify or --upgrade or --run or --controller/"),
    ]:
        assert cli_exit_code([*args, *bad]) == 2
        assert message in capsys.readouterr().err
