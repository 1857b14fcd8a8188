"""What a comparison checks before its first run, how it writes (streaming, no silent
overwrite) and what it returns: failed runs as rows, mean and spread over seeds."""

from __future__ import annotations

import csv
import io
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from rich.console import Console

from elastic_gym.cli import main
from elastic_gym.controllers.base import Controller
from elastic_gym.evaluation import Scenario, ScenarioError, compare, plan_runs
from elastic_gym.evaluation.episodes import run_group
from elastic_gym.evaluation.groups import plan_groups
from elastic_gym.evaluation.preflight import preflight
from elastic_gym.observers.finite_difference import FiniteDifferenceObserver
from elastic_gym.runtime.parallel import single_threaded

QUIET = Console(quiet=True)


class HoldPD(Controller):
    """PD + gravity compensation on the link state (rigid arms)."""

    name = "hold-pd"

    def __call__(self, obs, info):
        q, dq = self.split_state(obs)
        return self.model.gravity(q) + 400.0 * (info["reference"]["q"] - q) - 40.0 * dq


class BoomError(Exception):
    """A user's own exception type."""


class ExplodingController(HoldPD):
    """Raises its own exception type at the 5th call."""

    name = "exploding"

    def reset(self, obs, info):
        self.calls = 0

    def __call__(self, obs, info):
        self.calls += 1
        if self.calls == 5:
            raise BoomError("gain table exhausted")
        return super().__call__(obs, info)


class BrokenReset(HoldPD):
    name = "broken-reset"

    def reset(self, obs, info):
        raise KeyError("reference")


class DividingObserver(FiniteDifferenceObserver):
    """Raises ZeroDivisionError in its 3rd update."""

    name = "dividing"

    def update(self, obs, torque, dt):
        self.updates = getattr(self, "updates", 0) + 1
        if self.updates == 3:
            return 1 / 0
        return super().update(obs, torque, dt)


class CountingController(HoldPD):
    """Appends to ``folder/seen.log``, at each reset (in whichever process), how many rows
    runs.csv and how many figures the folder already holds."""

    name = "counting"

    def __init__(self, model, dt, folder: str) -> None:
        super().__init__(model, dt)
        self.folder = Path(folder)

    def reset(self, obs, info):
        path = self.folder / "runs.csv"
        rows = len(list(csv.DictReader(path.open()))) if path.exists() else 0
        with (self.folder / "seen.log").open("a") as log:
            log.write(f"{rows} {len(list(self.folder.glob('plots/*.png')))}\n")

    @staticmethod
    def seen(folder: Path) -> list[tuple[int, ...]]:
        lines = (folder / "seen.log").read_text().splitlines()
        return [tuple(int(n) for n in line.split()) for line in lines]


def scenario(**changes) -> Scenario:
    data = {
        "name": "checks",
        "duration": 0.02,
        "envs": [{"id": "TwoLinkRigid-v0", "kwargs": {"task": "regulation"}}],
        "controllers": [{"name": "hold", "class": HoldPD}],
        "state_sources": ["finite-difference"],
    }
    data.update(changes)
    return Scenario.from_dict(data)


def run(scn: Scenario, out: Path, **kwargs):
    return compare(scn, output_dir=out, workers=1, progress=False, console=QUIET, **kwargs)


# the rows and the refusals are the claims here, not the worker process: `workers=1` runs
# the worlds (and the checks before the first run) in this process
pytestmark = pytest.mark.usefixtures("jobs_in_this_process")


# ------------------------------------------------------------------ the output folder
def unwritable_folder(tmp_path: Path) -> Path:
    if os.geteuid() == 0:  # root writes anywhere but in read-only places
        if not os.path.isdir("/sys"):
            pytest.skip("no read-only folder to test with")
        return Path("/sys/elastic-gym-out")
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    return locked / "out"


def test_output_folder_that_cannot_hold_results_is_refused_before_any_run(tmp_path):
    a_file = tmp_path / "file.txt"
    a_file.write_text("mine")
    cases = [
        (a_file, NotADirectoryError, "is a file"),
        (a_file / "sub", NotADirectoryError, "is a file"),
        (unwritable_folder(tmp_path), PermissionError, "cannot write in"),
    ]
    for out, error, message in cases:
        with pytest.raises(error, match=message):
            run(scenario(), out)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["file.txt"] + (["locked"] if (tmp_path / "locked").exists() else [])
    )
    assert a_file.read_text() == "mine"


@pytest.mark.slow
def test_earlier_results_are_refused_unless_overwrite_which_removes_only_ours(tmp_path):
    run(scenario(), tmp_path)
    stale = tmp_path / "plots" / "old-scenario.png"
    stale.write_bytes(b"\x89PNG")
    (tmp_path / "notes.txt").write_text("mine")
    before = (tmp_path / "runs.csv").read_text()
    with pytest.raises(FileExistsError, match=r"earlier comparison \(runs\.csv.*--overwrite"):
        run(scenario(seeds=[1]), tmp_path)
    assert (tmp_path / "runs.csv").read_text() == before and stale.exists()

    result = run(scenario(seeds=[1]), tmp_path, overwrite=True)
    assert not stale.exists() and (tmp_path / "notes.txt").read_text() == "mine"
    assert [p.name for p in (tmp_path / "plots").iterdir()] == ["TwoLinkRigid_exact.png"]
    assert list(result.runs["seed"]) == [1]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "notes.txt",
        "plots",
        "runs.csv",
        "scenario.yaml",
        "summary.csv",
        "summary.md",
    ]


def test_cli_refuses_earlier_results_and_duplicate_seeds(tmp_path, capsys):
    (tmp_path / "runs.csv").write_text("env\n")
    with pytest.raises(SystemExit) as info:
        main(["compare", "--output", str(tmp_path), "--seeds", "0"])
    assert info.value.code == 2 and "--overwrite" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        main(["compare", "--output", str(tmp_path / "new"), "--seeds", "0", "0"])
    assert info.value.code == 2
    assert "seeds: duplicate seed(s) [0]" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("name", ["../escape", "a/b", "..", "x" * 300])
def test_scenario_name_stays_one_folder_inside_the_output_root(name):
    with pytest.raises(ScenarioError, match=r"^name: "):
        scenario(name=name)


@pytest.mark.slow
def test_labels_giving_the_same_or_too_long_figure_names_are_refused(tmp_path):
    same = scenario(
        envs=[
            {"id": "TwoLinkRigid-v0", "label": "arm a"},
            {"id": "TwoLinkRigid-v0", "label": "arm/a"},
        ]
    )
    with pytest.raises(
        ScenarioError,
        match=r"^envs: the env labels 'arm a' and 'arm/a' give "
        r"the same figure file name 'arm_a_exact\.png'",
    ):
        run(same, tmp_path / "a")
    long = scenario(model_errors=[{"label": "m" * 300, "link_mass": 1.1}])
    with pytest.raises(ScenarioError, match=r"^model_errors: .* \(the limit is 255\)"):
        run(long, tmp_path / "b")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    result = run(same, tmp_path / "c", plots=False)  # no figures: nothing to overwrite
    assert list(result.runs["env"]) == ["arm a", "arm/a"]


# ------------------------------------------------------------------ the grid
@pytest.mark.slow
@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (
            {
                "envs": [
                    {
                        "id": "TwoLinkRigid-v0",
                        "reset_options": {"initial_state": {"q": [0.1, 0.2, 0.3]}},
                    }
                ]
            },
            r"^envs\[0\]\.reset_options: ValueError: .*q",
        ),
        (
            {"envs": [{"id": "TwoLinkRigid-v0", "reset_options": {"initial_stat": {}}}]},
            r"^envs\[0\]\.reset_options: ConfigError: options\.initial_stat: unexpected field",
        ),
        (
            {"axes": {"enc": [{}, {"encoder": {"noise_std": -1.0}}]}},
            r"^axes\.enc\[1\]\.encoder\.noise_std: must be",
        ),
        (
            {"model_errors": [{"link_mass": [1.1, 1.2, 1.3]}]},
            r"^model_errors\[0\]: ValueError: parameter scaling 'link_mass' must be one or 2 ",
        ),
        (
            {"state_sources": [{"name": "finite-difference", "initial_estimate": [0.0] * 3}]},
            r"^state_sources\[0\]: ValueError: initial_estimate must be 4 finite numbers",
        ),
        (
            {"state_sources": [{"name": "finite-difference", "options": {"cutoff_hz": -5.0}}]},
            r"^state_sources\[0\]\.options: ValueError: options\.cutoff_hz: "
            r"Input should be greater than 0",
        ),
    ],
)
def test_what_would_fail_every_run_is_found_before_the_first(tmp_path, changes, message):
    with pytest.raises(ScenarioError, match=message):
        run(scenario(**changes), tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_plant_scaling_inside_axes_is_checked_when_loading():
    with pytest.raises(
        ScenarioError, match=r"^axes\.plant\[1\]\.plant_scaling\.link_mas: unexpected field"
    ):
        scenario(axes={"plant": [{}, {"plant_scaling": {"link_mas": 1.3}}]})
    with pytest.raises(ScenarioError, match=r"^envs\[0\]\.kwargs\.plant_scaling\.link_mass: .*> 0"):
        scenario(envs=[{"id": "TwoLinkRigid-v0", "kwargs": {"plant_scaling": {"link_mass": 0}}}])


@pytest.mark.slow
def test_missing_or_corrupted_policy_folder_is_found_before_the_first_run(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    from elastic_gym.training import TrainConfig

    missing = scenario(
        controllers=[{"name": "trained-policy", "options": {"run": str(tmp_path / "nope")}}]
    )
    nor = r"^controllers\[0\]\.options: .*nor a training run folder"
    with pytest.raises(ScenarioError, match=nor):
        run(missing, tmp_path / "out")
    broken = tmp_path / "broken"
    broken.mkdir()
    config = TrainConfig(
        env_id="TwoLinkRigid-v0", algo="sac", state="finite-difference", out_dir="x"
    )
    (broken / "config.yaml").write_text(yaml.safe_dump(config.to_dict()))
    (broken / "model.zip").write_bytes(b"not a zip archive")
    (broken / "vecnormalize.pkl").write_bytes(b"not a pickle")
    trusted = {"run": str(broken), "trust_pickle": True}
    corrupted = scenario(controllers=[{"name": "trained-policy", "options": trusted}])
    with pytest.raises(
        ScenarioError,
        match=r"^controllers\[0\]\.options: .*model\.zip cannot be "
        r"loaded as a sac model",
    ):
        run(corrupted, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    (broken / "config.yaml").write_text("algo: [sac\n")
    with pytest.raises(SystemExit) as info:
        main(["compare", "--policy", str(broken), "--output", str(tmp_path / "out")])
    assert info.value.code == 2  # a run folder: refused before its pickles are opened
    assert "elastic-gym export" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        argv = ["compare", "--policy", str(broken), "--trust-pickle"]
        main([*argv, "--output", str(tmp_path / "out")])
    assert info.value.code == 2
    assert "config.yaml is not a valid run configuration" in capsys.readouterr().err


# ------------------------------------------------------------------ runs and results
@pytest.mark.slow
def test_any_exception_in_a_users_controller_or_observer_is_a_failed_row(tmp_path):
    scn = scenario(
        duration=0.05,
        controllers=[
            {"name": "hold", "class": HoldPD},
            {"name": "exploding", "class": ExplodingController},
            {"name": "broken-reset", "class": BrokenReset, "sources": ["finite-difference"]},
        ],
        state_sources=["finite-difference", {"name": "dividing", "class": DividingObserver}],
    )
    result = run(scn, tmp_path)
    rows = {(r["controller"], r["source"]): r for r in result.runs.to_dict("records")}
    assert rows["hold", "finite-difference"]["status"] == "ok"
    assert rows["hold", "finite-difference"]["sim_time"] == pytest.approx(0.05)
    assert rows["exploding", "finite-difference"]["status"] == (
        "failed: BoomError: gain table exhausted"
    )
    assert rows["exploding", "finite-difference"]["sim_time"] == pytest.approx(0.004)
    assert rows["hold", "dividing"]["status"] == "failed: ZeroDivisionError: division by zero"
    assert rows["broken-reset", "finite-difference"]["status"] == "failed: KeyError: 'reference'"
    assert math.isnan(rows["broken-reset", "finite-difference"]["track_rms"])
    summary = result.summary.set_index(["controller", "source"])
    assert summary.loc[("hold", "dividing"), "status"].startswith("0/1 ok (failed: ")
    assert len(list((tmp_path / "plots").glob("*.png"))) == 1


@pytest.mark.slow
@pytest.mark.parametrize(
    ("batch_size", "expected"),
    [
        (1, [(0, 0), (1, 0), (2, 1), (3, 1)]),  # one run per world
        (2, [(0, 0), (0, 0), (2, 1), (2, 1)]),  # the two seeds of a plant share a world
    ],
)
def test_rows_and_figures_are_on_disk_as_soon_as_their_runs_finish(tmp_path, batch_size, expected):
    # a class of __main__ (a notebook's): the runs stay in this process, one after the other
    notebooks = type("Counting", (CountingController,), {"__module__": "__main__"})
    scn = scenario(
        seeds=[0, 1],
        axes={"plant": [{}, {"plant_scaling": {"link_mass": 1.1}}]},
        controllers=[
            {"name": "counting", "class": notebooks, "options": {"folder": str(tmp_path)}}
        ],
    )
    run(scn, tmp_path, batch_size=batch_size)
    # the last 4 resets are the runs' (the checks before the first run build them once more)
    assert CountingController.seen(tmp_path)[-4:] == expected


@pytest.mark.slow
def test_compare_returns_mean_and_spread_over_seeds(tmp_path, monkeypatch):
    scn = scenario(
        seeds=[0, 1, 2],
        duration=0.05,
        envs=[{"id": "TwoLinkRigid-v0", "kwargs": {"task": "regulation"}}],
    )
    result = run(scn, tmp_path)
    track = result.runs["track_rms"].to_numpy()
    assert len(set(track)) == 3  # the seeds draw different goals
    row = result.summary.iloc[0]
    assert row["seeds"] == 3
    assert row["track_rms"] == pytest.approx(np.mean(track), rel=1e-12)
    assert row["track_rms_std"] == pytest.approx(np.std(track, ddof=1), rel=1e-12)
    with (tmp_path / "summary.csv").open() as handle:
        assert float(next(csv.DictReader(handle))["track_rms_std"]) == row["track_rms_std"]

    monkeypatch.setitem(sys.modules, "pandas", None)  # pandas not installed
    plain = run(scn, tmp_path / "plain")
    assert (
        isinstance(plain.summary, list)
        and plain.summary[0]["track_rms_std"] == (row["track_rms_std"])
    )
    assert [r["track_rms"] for r in plain.runs] == list(track)


@pytest.mark.slow
@pytest.mark.parametrize(("batch_size", "worlds"), [(1, 4), (64, 2)])
def test_run_count_and_time_estimate_are_printed_first_and_hold(tmp_path, batch_size, worlds):
    scn = scenario(duration=0.2, seeds=[0, 1], state_sources=["finite-difference", "nicosia-tomei"])
    runs, _ = plan_runs(scn)
    estimate = preflight(scn, plan_groups(runs, batch_size, 1), workers=1)
    with single_threaded():  # as in a worker process, but here, where its CPU time counts
        for group in plan_groups(runs, batch_size, 1):
            run_group(group)  # once untimed: a kernel first used here compiles (cold cache)
        start = time.process_time()
        for group in plan_groups(runs, batch_size, 1):
            run_group(group)
    measured = time.process_time() - start  # CPU time: the machine's load does not enter
    assert 0.5 < estimate.cpu_seconds / measured < 2.0, (estimate.cpu_seconds, measured)
    assert estimate.seconds == estimate.cpu_seconds / estimate.share and 0 < estimate.share <= 1

    printed = io.StringIO()
    compare(
        scn,
        output_dir=tmp_path,
        workers=1,
        progress=False,
        plots=False,
        console=Console(file=printed, width=200),
        batch_size=batch_size,
    )
    first = printed.getvalue().splitlines()[0]
    assert first.startswith(f"checks: 4 runs in {worlds} worlds on 1 worker, about ")
    assert first.endswith(" s")
