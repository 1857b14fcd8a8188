"""Comparison runner: metrics on synthetic series, scenario validation, presets, runs, CLI."""

from __future__ import annotations

import csv
import math
import re
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import yaml
from helpers import GravityPD, rigid_scenario
from rich.console import Console

from elastic_gym.cli import main
from elastic_gym.controllers.base import Controller
from elastic_gym.envs.trajectories import timing_law
from elastic_gym.evaluation import (
    Scenario,
    ScenarioError,
    TimeSeries,
    compare,
    compute_metrics,
    execute,
    list_presets,
    load_preset,
    load_scenario,
    plan_runs,
)
from elastic_gym.evaluation.episodes import run_episode
from elastic_gym.evaluation.metrics import SETTLING_BAND, find_moves
from elastic_gym.evaluation.scenario import COMPARISON_INTEGRATOR

DT = 1e-3
QUIET = Console(quiet=True)


class Spy(GravityPD):
    """Records what a controller is given (runs in this process only)."""

    seen: list = []  # noqa: RUF012 - shared on purpose

    def __call__(self, obs, info):
        mass = float(np.mean(self.model.scaling.link_mass))
        Spy.seen.append((frozenset(obs), frozenset(info), mass))
        return super().__call__(obs, info)


class Unstable(Controller):
    """Positive position feedback: the arm runs away (the run must end early, not crash)."""

    name = "unstable"

    def __call__(self, obs, info):
        q, _ = self.split_state(obs)
        return self.model.gravity(q) + 5000.0 * (q - info["reference"]["q"] + 0.1)


# ---------------------------------------------------------------------------- metrics
def synthetic_move(response) -> TimeSeries:
    """Joint 1 moves 0 -> 1 rad in [0.5, 1.0] s; q follows the reference, then ``response``."""
    time = np.arange(0.0, 2.0 + DT / 2, DT)
    u = (time - 0.5) / 0.5
    s, ds = timing_law(u, 1)[:2]
    ds = np.where((u > 0) & (u < 1), ds / 0.5, 0.0)
    q_ref = np.stack([s, np.full_like(s, 0.3)], axis=1)
    dq_ref = np.stack([ds, np.zeros_like(ds)], axis=1)
    q = q_ref.copy()
    after = time > 1.0
    q[after, 0] += response(time[after] - 1.0)
    q[:, 1] += 2e-3 * np.sin(40.0 * time)  # the resting joint is not scored
    n = len(time)
    error = np.zeros((n, 4))
    error[:, 2:] = [0.3, 0.4]
    return TimeSeries(time, q, q_ref, dq_ref, np.full((n, 2), [3.0, 4.0]), error, ("q", "dq"))


def bump(t):
    """A 5 % overshoot lasting 0.2 s, then exactly at the target."""
    return np.where(t < 0.2, 0.05 * np.sin(np.pi * t / 0.2), 0.0)


def test_overshoot_and_settling_time_of_a_known_response():
    series = synthetic_move(bump)
    moves = find_moves(series)
    assert len(moves) == 1
    assert moves[0].target == pytest.approx([1.0, 0.3])
    assert series.time[moves[0].arrival] == pytest.approx(1.0, abs=DT)
    metrics = compute_metrics(series)
    assert metrics["overshoot_pct"] == pytest.approx(5.0, abs=1e-3)
    # leaves the 2 % band for the last time where 0.05 sin(pi t / 0.2) = 0.02, t in (0.1, 0.2)
    expected = 0.2 - 0.2 * math.asin(SETTLING_BAND / 0.05) / math.pi
    assert metrics["settling_time"] == pytest.approx(expected, abs=1.5 * DT)
    assert metrics["torque_rms"] == pytest.approx(5.0)
    assert metrics["est_rms_q"] == 0.0
    assert metrics["est_rms_dq"] == pytest.approx(0.5)
    assert math.isnan(metrics["torsion_max"])


def test_tracking_error_and_unsettled_move():
    series = synthetic_move(lambda t: np.full_like(t, 0.03))  # a 3 % offset that stays
    metrics = compute_metrics(series)
    assert metrics["settling_time"] == math.inf
    assert metrics["overshoot_pct"] == pytest.approx(3.0)
    error = np.linalg.norm(series.q - series.q_ref, axis=1)
    assert metrics["track_max"] == pytest.approx(error.max())
    assert metrics["track_rms"] == pytest.approx(np.sqrt(np.mean(error**2)))


def test_regulation_step_counts_as_a_move_from_the_initial_state():
    time = np.arange(0.0, 1.0, DT)
    q = np.stack([1.0 - np.exp(-time / 0.1), np.zeros_like(time)], axis=1)  # first order
    q_ref = np.tile([1.0, 0.0], (len(time), 1))
    zeros = np.zeros_like(q)
    series = TimeSeries(time, q, q_ref, zeros, zeros, np.zeros((len(time), 4)), ("q", "dq"))
    metrics = compute_metrics(series)
    assert metrics["overshoot_pct"] == 0.0
    assert metrics["settling_time"] == pytest.approx(-0.1 * math.log(SETTLING_BAND), abs=DT)
    assert math.isnan(compute_metrics(series, tracking=False)["settling_time"])


# ---------------------------------------------------------------------------- scenarios
@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"seed": [1]}, "seed"),
        ({"duration": -1.0}, "duration"),
        ({"seeds": [0, -2]}, "seeds[1]"),
        ({"envs": ["NoSuchArm-v0"]}, "envs[0].id"),
        ({"envs": [{"id": "TwoLinkRigid-v0", "kwargs": {"tsk": "x"}}]}, "envs[0].kwargs.tsk"),
        ({"controllers": ["motor-pd", "no-such-controller"]}, "controllers[1].name"),
        ({"controllers": [{"name": "motor-pd", "sources": ["ekf"]}]}, "controllers[0].sources"),
        ({"controllers": [{"name": "motor-pd", "gains": {}}]}, "controllers[0].gains"),
        ({"state_sources": [True, {"name": "deluca", "options": 3}]}, "state_sources[1].options"),
        ({"state_sources": ["kalman"]}, "state_sources[0].name"),
        ({"state_sources": [True, "true"]}, "state_sources"),
        ({"model_errors": [{"link_mas": 1.1}]}, "model_errors[0].link_mas"),
        (
            {"axes": {"plant": [{"plant_scaling": {"link_mass": 1.3}}, {"encoders": {}}]}},
            "axes.plant[1].encoders",
        ),
        ({"axes": {"seed": [{}]}}, "axes.seed"),
    ],
)
def test_invalid_field_is_named(change, field):
    with pytest.raises(ScenarioError) as info:
        Scenario.from_dict(rigid_scenario(**change))
    assert str(info.value).startswith(f"{field}:"), str(info.value)


def test_invalid_yaml_file_and_unknown_names(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                **rigid_scenario(controllers=["motor-pd"]),
                "state_sources": ["true", "nicosia-tomei", "oracle"],
            }
        )
    )
    with pytest.raises(ScenarioError, match=r"state_sources\[2\]\.name.*valid: \[.*'ekf'"):
        load_scenario(path)
    path.write_text("envs: [TwoLinkRigid-v0\n")
    with pytest.raises(ScenarioError, match="invalid YAML"):
        load_scenario(path)
    with pytest.raises(ValueError, match=r"unknown preset 'nope'; valid: .*'default'"):
        load_preset("nope")


@pytest.mark.parametrize("name", list_presets())
def test_shipped_preset_parses_and_plans(name):
    scenario = load_preset(name)
    assert scenario.name == name
    try:
        runs, _ = plan_runs(scenario)
    except ScenarioError as exc:  # a controller/observer module that has not landed yet
        assert "not available" in str(exc)
        pytest.skip(str(exc))
    assert runs, f"preset {name} has no applicable run"


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        (
            {"controllers": [{"name": "x", "class": int}]},
            r"^controllers\[0\]\.class: .*int.* not a subclass of Controller",
        ),
        (
            {"state_sources": [{"name": "x", "class": "no_such_module:Observer"}]},
            r"^state_sources\[0\]\.class: cannot import class 'no_such_module:Observer'",
        ),
    ],
)
def test_explicit_classes_are_checked_when_planning(entry, message):
    scenario = Scenario.from_dict(rigid_scenario(**entry))
    with pytest.raises(ScenarioError, match=message):
        plan_runs(scenario)


def test_plan_skips_inapplicable_and_merges_axes():
    scenario = Scenario.from_dict(
        rigid_scenario(
            state_sources=[True, "deluca"],
            axes={"plant": [{}, {"label": "heavy", "plant_scaling": {"link_mass": 1.1}}]},
            model_errors=[{}, {"link_mass": 1.2}],
            seeds=[0, 1],
        )
    )
    runs, skipped = plan_runs(scenario)
    assert len(runs) == 2 * 2 * 2 and len(skipped) == 8  # deluca is for elastic arms
    assert all("deluca" in s.reason and "elastic" in s.reason for s in skipped)
    heavy = [r for r in runs if r.labels["plant"] == "heavy"]
    assert heavy[0].env_kwargs == {
        "integrator": COMPARISON_INTEGRATOR,
        "task": "regulation",
        "plant_scaling": {"link_mass": 1.1},
    }
    assert {r.labels["model_error"] for r in runs} == {"exact", "link_mass=1.2"}
    assert scenario.identity_columns == (
        "env",
        "plant",
        "model_error",
        "controller",
        "source",
        "seed",
    )


# ---------------------------------------------------------------------------- runs
def test_controller_sees_only_public_information_and_the_perturbed_model():
    Spy.seen.clear()
    scenario = Scenario.from_dict(
        rigid_scenario(
            controllers=[{"name": "spy", "class": Spy}],
            state_sources=["finite-difference"],
            model_errors=[{"link_mass": 1.25}],
            duration=0.01,
        )
    )
    results = [run_episode(spec) for spec in plan_runs(scenario)[0]]  # in this process
    assert results[0].ok and len(results[0].series) == 11
    assert {keys for keys, _, _ in Spy.seen} == {frozenset({"state", "reference"})}
    assert all(info <= {"time", "reference"} for _, info, _ in Spy.seen)
    assert {mass for _, _, mass in Spy.seen} == {1.25}


def test_open_loop_row_is_the_excitation_task_driven_by_zero_action():
    """The ``open-loop`` controller adds nothing: its comparison row on the ``excitation``
    task (Cristofaro & De Luca's open-loop torque, applied by the env) is the env stepped
    with zero actions, torque and link motion bit for bit."""
    scenario = Scenario.from_dict(
        rigid_scenario(
            controllers=["open-loop"],
            state_sources=[True],
            duration=0.05,
            envs=[{"id": "TwoLinkRigid-v0", "kwargs": {"task": "excitation"}}],
        )
    )
    spec = plan_runs(scenario)[0][0]
    row = run_episode(spec)
    assert row.ok and row.series is not None
    env = gym.make(spec.env_id, **spec.env_kwargs)
    _, info = env.reset(seed=spec.seed)
    q, torque = [info["true_state"]["q"]], [info["torque"]]
    for _ in range(len(row.series) - 1):
        _, _, _, _, info = env.step(np.zeros(2))
        q.append(info["true_state"]["q"])
        torque.append(info["torque"])
    env.close()
    assert np.abs(np.array(torque)).min() > 1.0  # the task drives the arm
    np.testing.assert_array_equal(np.array(torque), row.series.torque)
    np.testing.assert_array_equal(np.array(q), row.series.q)


def test_the_former_runner_module_keeps_earlier_imports_working():
    """`elastic_gym.evaluation.runner` (deprecated, CHANGELOG) hands on the very objects
    of the comparison's stages."""
    import importlib

    runner = importlib.import_module("elastic_gym.evaluation.runner")
    homes = ("closed_loop", "episodes", "execute", "grid", "world")
    modules = [importlib.import_module(f"elastic_gym.evaluation.{home}") for home in homes]
    for name in runner.__all__:
        assert any(getattr(m, name, None) is getattr(runner, name) for m in modules), name


@pytest.mark.slow
@pytest.mark.usefixtures("jobs_in_this_process")  # the results are the claim
def test_diverging_run_is_reported_not_raised():
    scenario = Scenario.from_dict(
        rigid_scenario(
            controllers=[
                {"name": "unstable", "class": Unstable},
                {"name": "pd", "class": GravityPD},
            ],
            state_sources=[True],
            duration=1.0,
            envs=[
                {"id": "TwoLinkRigid-v0", "kwargs": {"task": "regulation", "max_velocity": 20.0}}
            ],
        )
    )
    results = execute(plan_runs(scenario)[0], workers=1, progress=False)
    unstable, stable = results
    assert unstable.status.startswith("terminated: ") and not unstable.ok
    assert "velocity limit" in unstable.status and unstable.metrics["sim_time"] < 1.0
    assert stable.ok and stable.metrics["sim_time"] == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        (
            {"controllers": [{"name": "pd", "class": GravityPD, "options": {"gain": 1.0}}]},
            r"^controllers\[0\]\.options\.gain: unexpected option; valid: \['kp', 'kd'\]",
        ),
        (
            {"controllers": [{"name": "pd", "class": GravityPD, "options": {1: 2.0}}]},
            r"^controllers\[0\]\.options\.1: unexpected option",
        ),
        (
            {
                "controllers": [
                    "motor-pd",
                    {"name": "feedforward-state-feedback", "options": {"omegaa": 30.0}},
                ],
                "envs": ["TwoLinkElastic-v0"],
            },
            r"^controllers\[1\]\.options\.omegaa: unexpected option; valid: \[.*'omega'",
        ),
        (
            {"state_sources": [{"name": "deluca", "options": {"acceleration": "ideal"}}]},
            r"^state_sources\[0\]\.options\.acceleration: fixed to 'accelerometer' by the name",
        ),
        (
            {"state_sources": [{"name": "ekf", "options": {"alpa": 1.0}}]},
            r"^state_sources\[0\]\.options\.alpa: unexpected option; valid: \['alpha'",
        ),
    ],
)
def test_options_are_bound_to_the_constructor_before_any_run(entry, message):
    scenario = Scenario.from_dict(rigid_scenario(**entry))
    with pytest.raises(ScenarioError, match=message):
        plan_runs(scenario)


@pytest.mark.slow
def test_compare_in_worker_processes_writes_tables_and_plots(tmp_path):
    scenario = Scenario.from_dict(
        rigid_scenario(
            envs=[
                {
                    "id": "TwoLinkElastic-v0",
                    "kwargs": {
                        "task": "tracking",
                        "task_options": {"n_moves": 1, "move_time": 0.2, "dwell_time": 0.05},
                    },
                }
            ],
            duration=0.4,
        )
    )
    result = compare(scenario, output_dir=tmp_path, workers=2, progress=False, console=QUIET)
    assert list(result.runs["status"]) == ["ok", "ok"]
    with (tmp_path / "runs.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [row["source"] for row in rows] == ["true", "finite-difference"]
    assert float(rows[0]["est_rms_dq"]) == 0.0 < float(rows[1]["est_rms_dq"])
    assert float(rows[0]["track_rms"]) > 0.0 and float(rows[0]["torsion_max"]) > 0.0
    markdown = (tmp_path / "summary.md").read_text()
    assert re.search(r"^\| source +\|.*\| est\. RMS q' \[rad/s\] \|", markdown, re.M)
    assert re.search(r"^\| finite-difference \|", markdown, re.M)
    pngs = list((tmp_path / "plots").glob("*.png"))
    assert len(pngs) == 1 and pngs[0].read_bytes()[:4] == b"\x89PNG"
    again = load_scenario(tmp_path / "scenario.yaml")
    assert again.controllers[0].cls.endswith(":GravityPD")


@pytest.mark.slow
@pytest.mark.usefixtures("jobs_in_this_process")  # the rows are the claim, not the workers
def test_cli_default_preset_short_run(tmp_path, capsys):
    try:
        runs, _ = plan_runs(load_preset("default").with_overrides(seeds=[0]))
    except ScenarioError as exc:
        pytest.skip(str(exc))
    code = main(
        [
            "compare",
            "--duration",
            "0.05",
            "--seeds",
            "0",
            "--output",
            str(tmp_path),
            "--no-progress",
            "--no-plots",
            "--workers",
            "1",
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "est. RMS q'" in out and "deluca" in out
    with (tmp_path / "runs.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == len(runs) and {row["status"] for row in rows} == {"ok"}


@pytest.mark.slow
def test_compare_works_without_the_rl_extra(tmp_path):
    """`pip install .` (the README's main command) has no stable-baselines3 or torch (the
    `rl` extra): the CLI and a comparison must not need them."""
    scenario = tmp_path / "small.yaml"
    scenario.write_text(
        yaml.safe_dump(
            {
                "name": "small",
                "duration": 0.05,
                "seeds": [0],
                "envs": ["TwoLinkElastic-v0"],
                "controllers": ["feedforward-state-feedback"],
                "state_sources": ["deluca"],
            }
        )
    )
    blocked = ("stable_baselines3", "sb3_contrib", "torch")
    code = (  # an import of a blocked package fails as if it were not installed
        "import importlib.abc, sys\n"
        "class NotInstalled(importlib.abc.MetaPathFinder):\n"
        "    def find_spec(self, name, path, target=None):\n"
        f"        if name.partition('.')[0] in {blocked!r}:\n"
        "            raise ModuleNotFoundError(f'No module named {name!r}')\n"
        "sys.meta_path.insert(0, NotInstalled())\n"
        "from elastic_gym.cli import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )

    def cli(*argv: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=300
        )

    result = cli(
        "compare",
        "--config",
        str(scenario),
        "--output",
        str(tmp_path / "out"),
        "--no-progress",
        "--no-plots",
        "--workers",
        "1",
    )
    assert result.returncode == 0, result.stderr[-2000:]
    with (tmp_path / "out" / "runs.csv").open() as handle:
        assert [row["status"] for row in csv.DictReader(handle)] == ["ok"]
    result = cli("train", "--steps", "10", "--out", str(tmp_path / "run"))  # RL: said clearly
    assert result.returncode == 1 and "needs the 'rl' extra" in result.stderr, result.stderr
    assert not (tmp_path / "run").exists()


def test_cli_errors_name_the_field(tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "envs": ["TwoLinkRigid-v0"],
                "controllers": ["motor-pd"],
                "state_sources": ["true"],
                "duraton": 1.0,
            }
        )
    )
    with pytest.raises(SystemExit) as info:
        main(["compare", "--config", str(path)])
    assert info.value.code == 2
    assert "duraton: unexpected field" in capsys.readouterr().err
    assert main(["compare", "--list-presets"]) == 0
    assert "default" in capsys.readouterr().out.split()
