"""The robustness study of policies (``studies/robust_study.py``): its plants are the
plants they say, its rows are the ``elastic-gym train`` commands they print, its targets
are computed from the evaluations, and a tiny study writes every report file."""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import functools
import io
import json
import shutil
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pybullet as p
import pytest
import yaml

from elastic_gym.cli import main
from elastic_gym.policy import build_policy_env

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "studies"))
import robust_study as rs

TWO_LINK = "elastic_gym/TwoLinkElastic-v0"
Q = np.array([0.3, -0.7])
SHORT_TASK = {  # one move of 0.3 s (3 s episodes of two moves in the study)
    "task": "tracking",
    "task_options": {"n_moves": 1, "move_time": 0.3, "dwell_time": 0.2},
    "episode_time": 0.5,
}


@functools.cache
def _printed_in_process(argv: tuple[str, ...]) -> dict:
    """What ``elastic-gym train <argv> --print-config`` prints, from the command's `main`
    in this process (the study's `printed_config` starts one subprocess per argv)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["train", *argv, "--print-config"]) == 0
    (config,) = yaml.safe_load(out.getvalue())
    return config


@pytest.fixture
def in_process(monkeypatch):
    """The rows' configs from the train command's `main` in this process, not from one
    subprocess per row (that the two agree is asserted once, below)."""
    monkeypatch.setattr(rs, "printed_config", _printed_in_process)


def _env(kwargs: dict):
    return gym.make_vec(TWO_LINK, 1, vectorization_mode="vector_entry_point", **kwargs)


def _gravity_at_rest(sim) -> np.ndarray:
    """The joint torques PyBullet needs to hold the links at Q at rest."""
    zero = [0.0] * len(Q)
    return np.array(
        p.calculateInverseDynamics(
            sim.bodies[0], Q.tolist(), zero, zero, physicsClientId=sim.client
        )
    )


def test_the_plants_change_the_simulated_plant_and_only_it():
    envs = {name: _env(kwargs) for name, kwargs in rs.PLANTS.items()}
    try:
        batch = {name: env.unwrapped.batch for name, env in envs.items()}
        plant = {name: b.sim.plants for name, b in batch.items()}
        nominal = plant["nominal"]
        gravity = {name: _gravity_at_rest(b.sim) for name, b in batch.items()}
        limit = batch["nominal"].torque_limit
        for factor, name in ((0.7, "mass0.7"), (1.3, "mass1.3")):
            # heavier links: a larger gravity torque at rest, in PyBullet and in the chain
            assert np.allclose(gravity[name], factor * gravity["nominal"], rtol=1e-12)
            assert np.allclose(
                plant[name].models[0].gravity(Q), factor * nominal.models[0].gravity(Q), rtol=1e-12
            )
        for fraction, name in ((0.01, "coulomb1%"), (0.03, "coulomb3%")):
            assert np.allclose(plant[name].coulomb_pos[0], fraction * limit, rtol=1e-12)
        assert np.array_equal(nominal.coulomb_pos[0], np.zeros(2))
        assert np.allclose(plant["K0.9"].K, 0.9 * nominal.K, rtol=1e-12)
        assert np.allclose(1 / plant["B1.1"].B_inv, 1.1 / nominal.B_inv, rtol=1e-12)
        for name in rs.PLANTS:  # what a plant does not change is nominal
            assert np.array_equal(plant[name].K, nominal.K) == (name != "K0.9")
            assert np.array_equal(plant[name].B_inv, nominal.B_inv) == (name != "B1.1")
            assert np.array_equal(gravity[name], gravity["nominal"]) == ("mass" not in name)
            assert batch[name].control_dt == 1e-3  # a sensor delay of 1 period is 1 ms
        # the delayed plant's encoders and accelerometers read the nominal ones 1 ms late
        readings = {}
        for name in ("nominal", "delay1ms"):
            obs, _ = envs[name].reset(seed=5)
            readings[name] = [obs]
            for _ in range(6):
                readings[name].append(envs[name].step(np.full((1, 2), 3.0))[0])
        for k in range(1, 6):
            for key in ("motor_position", "acceleration"):
                assert np.array_equal(readings["delay1ms"][k + 1][key], readings["nominal"][k][key])
        assert not np.array_equal(
            readings["delay1ms"][3]["motor_position"], readings["nominal"][3]["motor_position"]
        )
    finally:
        for env in envs.values():
            env.close()


@pytest.mark.slow
@pytest.mark.usefixtures("in_process")
def test_the_evaluation_plants_switch_a_randomized_run_s_randomization_off():
    (row,) = [row for row in rs.ROWS if row.key == "ppo-true-robust"]
    config = row.config(0, Path("runs"))
    settings, _ = config.settings()
    spec = config.policy_spec(settings)
    assert "plant_scaling.link_mass" in spec.env_kwargs["randomize"]
    training = build_policy_env(spec, spec.make_env(1))
    heavy = build_policy_env(spec, spec.make_env(1, rs.PLANTS["mass1.3"]))
    nominal = _env({})
    try:
        _, info = training.reset(seed=3)
        assert np.isfinite(info["plant"]["plant_scaling.link_mass"]).all()  # a drawn plant
        _, info = heavy.reset(seed=3)
        assert "plant_scaling.link_mass" not in info["plant"]
        sim = heavy.unwrapped.batch.sim
        assert np.allclose(
            _gravity_at_rest(sim), 1.3 * _gravity_at_rest(nominal.unwrapped.batch.sim), rtol=1e-12
        )
    finally:
        for env in (training, heavy, nominal):
            env.close()


@pytest.mark.slow  # one subprocess
def test_the_rows_are_the_train_commands_they_print(tmp_path, monkeypatch):
    (residual,) = [row for row in rs.ROWS if row.key == "residual-integral-robust"]
    argv = tuple(residual.argv(1, tmp_path))  # the command itself, in a subprocess
    assert rs.printed_config(argv) == _printed_in_process(argv)
    monkeypatch.setattr(rs, "printed_config", _printed_in_process)  # the other rows
    keys = [row.key for row in rs.ROWS]
    assert len(keys) == len(set(keys)) == len(rs.TRAINING)
    seeds = {row.key: row.seeds for row in rs.ROWS}
    three = (
        "ppo-deluca-robust",
        "rppo-deluca-robust",
        "rppo-sensors-robust",
        "rppo-sensors-distilled",
        "residual-integral-robust",
    )
    assert all(seeds[key] == (0, 1, 2) for key in three)
    assert all(len(s) == 1 for key, s in seeds.items() if key not in three)
    for row in rs.ROWS:
        config = row.config(1, tmp_path)
        assert config.out_dir == str(tmp_path / row.key / "seed1") and config.seed == 1
        assert config.total_steps is None  # the budget is the file's n_timesteps
        line = rs.command(row, 1, tmp_path)
        assert line.startswith("elastic-gym train ") and f"--out {tmp_path}/{row.key}/seed1" in line
        assert (config.hyperparams_file is None) == (row.hyperparams_file is None)
    (rppo,) = [row for row in rs.ROWS if row.key == "rppo-sensors-robust"]
    config = rppo.config(0, tmp_path)
    assert (config.algo, config.state, config.frame_stack) == ("recurrentppo", "sensors", 1)
    assert Path(config.hyperparams_file).name == "recurrentppo-robust.yaml"
    (distilled,) = [row for row in rs.ROWS if row.key == "rppo-sensors-distilled"]
    config = distilled.config(0, tmp_path)
    assert (config.algo, config.state, config.frame_stack) == ("recurrentppo", "sensors", 1)
    assert config.settings()[0].distill is not None
    assert (
        distilled.label
        == "RecurrentPPO, distilled from the plant teacher (DAgger), trained randomized"
    )
    (memory,) = [row for row in rs.ROWS if row.key == "rppo-deluca-robust"]
    config = memory.config(0, tmp_path)
    assert (config.algo, config.state) == ("recurrentppo", "deluca")
    assert Path(config.hyperparams_file).name == "recurrentppo-deluca-robust.yaml"
    (residual,) = [row for row in rs.ROWS if row.key == "residual-integral-robust"]
    assert residual.config(0, tmp_path).action == {
        "kind": "residual",
        "residual": "integral-state-feedback",
    }


def _records(values: dict[tuple[str, str], list[float]], wall: str = "") -> list[dict]:
    """Evaluation records: (row, plant) -> one RMS per training seed (one episode each)."""
    records = []
    for (row, plant), per_seed in values.items():
        for seed, rms in enumerate(per_seed):
            records.append(
                {
                    "row": row,
                    "seed": str(seed),
                    "plant": plant,
                    "tracking_rms": str(rms),
                    "wall_time": wall if row == "ppo-true-nominal" else "",
                }
            )
    return records


def test_the_targets_compute_their_verdicts_from_the_numbers():
    integral, fd, eq13 = (
        "integral-state-feedback-deluca",
        "motor-pd-finite-difference",
        ("feedforward-state-feedback-deluca"),
    )
    records = _records(
        {
            ("ppo-deluca-robust", "mass1.3"): [1e-3, 2e-3, 3e-3],  # mean 2e-3
            (integral, "mass1.3"): [2e-3],  # equal: not below
            ("ppo-deluca-robust", "coulomb1%"): [1e-3, 1e-3, 1e-3],
            (integral, "coulomb1%"): [1.5e-3],
            ("ppo-deluca-robust", "nominal"): [7e-4, 7e-4, 7e-4],  # at the bound: met
            ("rppo-deluca-robust", "mass1.3"): [1e-3, 1e-3, 1e-3],
            ("rppo-deluca-robust", "nominal"): [8e-4, 6e-4, 7.3e-4],  # mean 7.1e-4: missed
            (integral, "nominal"): [1e-4],
            ("rppo-sensors-robust", "K0.9"): [2e-3],
            ("rppo-sensors-distilled", "K0.9"): [0.5e-3, 0.7e-3, 0.9e-3],  # mean 7e-4
            (fd, "K0.9"): [3e-3],
            (eq13, "K0.9"): [3e-3],  # a third: 1e-3
            ("residual-integral-robust", "mass1.3"): [0.9e-3],
            ("residual-integral-robust", "nominal"): [1.3e-4],
            ("ppo-true-nominal", "nominal"): [1e-4],
        },
        wall="1000.0",
    )
    lines = {t.name: t for t in rs.targets(records)}
    assert len(lines) == 18
    verdicts = {name: t.verdict for name, t in lines.items()}
    mass = lines["randomized PPO on De Luca, link mass ×1.3"]
    assert (mass.measured, mass.bound, mass.verdict) == (pytest.approx(2e-3), 2e-3, "missed")
    assert verdicts["randomized PPO on De Luca, Coulomb 1 %"] == "met"
    assert verdicts["randomized PPO on De Luca, nominal"] == "met"
    assert verdicts["randomized RecurrentPPO on De Luca, link mass ×1.3"] == "met"
    assert verdicts["randomized RecurrentPPO on De Luca, nominal"] == "missed"
    assert verdicts["randomized RecurrentPPO on De Luca, Coulomb 1 %"] == "—"  # not evaluated
    k_motor = lines["randomized RecurrentPPO on raw sensors, K ×0.9, vs motor PD"]
    k_eq13 = lines["randomized RecurrentPPO on raw sensors, K ×0.9, vs eq. (13)"]
    assert (k_motor.verdict, k_eq13.verdict) == ("met", "missed")
    assert k_eq13.bound == pytest.approx(1e-3, rel=1e-12)
    k_distilled = lines["randomized RecurrentPPO distilled on raw sensors, K ×0.9, vs eq. (13)"]
    assert (k_distilled.measured, k_distilled.verdict) == (pytest.approx(7e-4), "met")
    residual = lines["randomized residual on eq. (13) + integral action, De Luca, link mass ×1.3"]
    assert residual.bound == pytest.approx(1e-3) and residual.verdict == "met"
    nominal = lines["randomized residual on eq. (13) + integral action, De Luca, nominal"]
    assert nominal.bound == pytest.approx(1.2e-4) and nominal.verdict == "missed"
    assert verdicts["nominal PPO on the true state, nominal"] == "met"
    wall = lines["nominal PPO on the true state, training wall time"]
    assert (wall.measured, wall.bound, wall.unit, wall.verdict) == (1000.0, 900.0, "s", "missed")
    # B x 1.1 was not evaluated: no verdict
    assert verdicts["randomized RecurrentPPO on raw sensors, B ×1.1, vs motor PD"] == "—"
    assert lines["randomized PPO on De Luca, nominal"].line()["bound"].startswith("≤ 7.00e-04 rad")
    assert mass.line()["bound"].startswith("< 2.00e-03 rad")


@pytest.mark.slow
@pytest.mark.usefixtures("in_process")
def test_a_tiny_study_writes_table_csv_targets_and_figure(tmp_path, capsys):
    runs, out = tmp_path / "runs", tmp_path / "out"
    classical = (
        (rs.EQ13, "eq. (13)", ("deluca",)),
        ("motor-pd", "motor PD", (rs.ENCODERS,)),
        (rs.INTEGRAL, "integral action, load identified", ("true",), rs.LOAD_IDENTIFIED),
    )
    small = "--algo ppo --state true --hyperparams n_envs=4 batches=1 batch_size=64"
    small += " --eval-freq 256 --eval-episodes 1"  # two learning-curve points, not twenty
    small += f" --env-kwargs '{json.dumps(SHORT_TASK)}'"  # training episodes of 0.5 s
    rows = (rs.Row("ppo-true-nominal", (0,), None, small, eval_task=SHORT_TASK),)
    study = dataclasses.replace(  # the shipped 64 arms and 2.6 s episodes: too slow
        rs.ROBUST_STUDY, classical=classical, rows=rows, task=SHORT_TASK
    )
    argv = ["--rows", "ppo-true-nominal", "--steps", "512", "--plants", "nominal", "mass1.3"]
    argv += ["--episodes", "1", "--runs", str(runs), "--out", str(out)]
    rs.run(study, argv)
    assert (runs / "ppo-true-nominal" / "seed0" / "summary.json").is_file()
    with open(out / "evaluations.csv") as handle:
        records = list(csv.DictReader(handle))
    identified = "integral-state-feedback+load_identification=shared-true"  # with its options
    keys = ["feedforward-state-feedback-deluca", "motor-pd-finite-difference", identified]
    keys.append("ppo-true-nominal")
    expected = {(key, plant) for key in keys for plant in ("nominal", "mass1.3")}
    assert {(r["row"], r["plant"]) for r in records} == expected
    assert len(records) == len(expected)  # one episode each
    assert {r["episode_seed"] for r in records} == {"100000"}
    load = {r["plant"]: float(r["tracking_rms"]) for r in records if r["row"] == identified}
    assert load["mass1.3"] < 1.2 * load["nominal"]  # the options reached the controller
    table = (out / "table.md").read_text().splitlines()
    assert len(table) == 2 + len(keys)
    assert "link mass ×1.3" in table[0] and "K ×0.9" in table[0]
    (ppo,) = [line for line in table if "PPO, pure RL, trained nominal" in line]
    heavy = [r for r in records if r["row"] == "ppo-true-nominal" and r["plant"] == "mass1.3"]
    assert f"{float(heavy[0]['tracking_rms']):.2e}" in ppo
    with open(out / "table.csv") as handle:
        lines = {line["row"]: line for line in csv.DictReader(handle)}
    assert float(lines["ppo-true-nominal"]["mass1.3"]) == float(heavy[0]["tracking_rms"])
    targets = (out / "targets.md").read_text()
    assert "| nominal PPO on the true state, training wall time |" in targets
    verdicts = [line.rsplit("|", 2)[1].strip() for line in targets.splitlines()[2:]]
    assert verdicts.count("—") == 16  # the rows and loops not evaluated here
    assert (out / "robust_rms.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "learning_curves.png").is_file()
    assert "elastic-gym" in (out / "stamp.md").read_text()
    (run_line,) = [line for line in (out / "runs.md").read_text().splitlines() if "`ppo" in line]
    assert run_line.startswith("| `ppo-true-nominal` | 0 | 512 |") and run_line.endswith("| — |")
    before = (out / "evaluations.csv").read_text()
    capsys.readouterr()
    rs.run(study, [*argv, "--report"])  # cached: nothing evaluated again
    assert "evaluated" not in capsys.readouterr().out
    assert (out / "evaluations.csv").read_text() == before
    summary = runs / "ppo-true-nominal" / "seed0" / "summary.json"
    summary.write_text(summary.read_text().replace('"wall_time": ', '"wall_time": 1'))
    rs.run(study, [*argv, "--report"])  # a run trained again since: evaluated again
    log = capsys.readouterr().out
    assert log.count("evaluated ppo-true-nominal seed 0") == 2 and log.count("evaluated") == 2
    with open(out / "evaluations.csv") as handle:
        again = list(csv.DictReader(handle))
    assert len(again) == len(records)
    (wall,) = {r["wall_time"] for r in again if r["row"] == "ppo-true-nominal"}
    assert wall == str(json.loads(summary.read_text())["wall_time"])
    files = ("runs.md", "curves.csv", "evaluations.csv", "table.csv")
    kept = {name: (out / name).read_text() for name in files}
    shutil.rmtree(runs)  # a report on a machine without the run folders loses nothing
    rs.run(study, [*argv, "--report"])
    assert "evaluated" not in capsys.readouterr().out
    assert {name: (out / name).read_text() for name in files} == kept


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["--rows", "ppo-true-nominal", "nope"],
            "--rows: unknown rows ['nope']; valid: ['ppo-true",
        ),
        (["--plants", "mass2"], "--plants: unknown plants ['mass2']; valid: ['nominal', 'mass0.7'"),
        (["--episodes", "0"], "--episodes: must be >= 1, got 0"),
    ],
)
def test_unknown_rows_plants_and_no_episodes_are_refused(argv, message, tmp_path, capsys):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exit_:
        rs.run(rs.ROBUST_STUDY, [*argv, "--runs", str(tmp_path / "runs"), "--out", str(out)])
    assert exit_.value.code == 2 and message in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "runs").exists()


def test_the_figure_draws_seeds_of_equal_rms(tmp_path):
    """Three seeds of equal RMS: their mean rounds below their minimum (a negative
    whisker matplotlib refuses); the figure draws them without whiskers."""
    x = next(v for v in (1.141e-5 * (1 + k * 1e-9) for k in range(1000)) if np.mean([v] * 3) < v)
    records = [
        {**r, "label": "residual", "state": "deluca", "algo": "ppo", "policy_steps": ""}
        for r in _records({("residual-integral-robust", "nominal"): [x, x, x]})
    ]
    (line,) = rs.table(records)
    assert line["nominal"] < line["nominal min"] == x
    rs.plot([line], tmp_path)
    assert (tmp_path / "robust_rms.png").stat().st_size > 0
