"""Training's round of fault injection: an overwrite that keeps the earlier run until the new
one is complete, a folder in use named as such, options refused before any worker starts,
hyper-parameters outside their meaning refused, and run files written whole."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import pytest
from helpers import folder_holder

from elastic_gym.runtime.folder_lock import LOCK_FILE
from elastic_gym.runtime.parallel import Interrupted
from elastic_gym.training import RunFolder, TrainConfig
from elastic_gym.training.run_folder import INCOMING, REPLACED, REPLACING


def earlier_run(folder: Path) -> dict[str, bytes]:
    """A finished earlier run in ``folder`` (its files and contents), a user's file beside."""
    files = {
        "model.zip": b"old model",
        "vecnormalize.pkl": b"old statistics",
        "config.yaml": b"old: config\n",
        "best_model.zip": b"old best",
        "summary.json": b"{}",
        "seed1/summary.json": b"{}",
    }
    for name, data in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(data)
    (folder / "notes.txt").write_text("mine")
    return files


def contents(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (but the writer's lock file) and its bytes."""
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != LOCK_FILE
    }


# ------------------------------------------------------------------ overwrite: write beside
def test_an_interrupted_overwrite_keeps_the_earlier_run_whole_and_says_so(tmp_path):
    before = {**earlier_run(tmp_path), "notes.txt": b"mine"}
    folder = RunFolder(tmp_path)
    with (
        pytest.raises(Interrupted, match="kept the earlier run in"),
        folder.create(overwrite=True) as run,
    ):
        assert run.target.path == tmp_path / INCOMING
        (run.target.path / "model.zip").write_bytes(b"half a new model")
        (run.target.path / "tb").mkdir()
        assert contents(tmp_path) == {**before, f"{INCOMING}/model.zip": b"half a new model"}
        raise KeyboardInterrupt
    assert contents(tmp_path) == before  # nothing of the new run, the earlier one whole


def test_a_failed_overwrite_keeps_the_earlier_run(tmp_path):
    before = {**earlier_run(tmp_path), "notes.txt": b"mine"}
    with pytest.raises(RuntimeError, match="loss is NaN"), RunFolder(tmp_path).create(True) as run:
        run.target.write_summary({"half": True})
        raise RuntimeError("loss is NaN")
    assert contents(tmp_path) == before


def test_a_finished_overwrite_replaces_the_earlier_runs_files_and_only_those(tmp_path):
    earlier_run(tmp_path)
    folder = RunFolder(tmp_path)
    with folder.create(overwrite=True) as run:
        (run.target.path / "model.zip").write_bytes(b"new model")
        (run.target.path / "tb").mkdir()
        (run.target.path / "tb" / "events").write_bytes(b"new events")
        run.target.write_summary({"policy_steps": 8})
        run.finish()  # in place at once: what follows cannot lose it
        assert (tmp_path / "model.zip").read_bytes() == b"new model"
    assert contents(tmp_path) == {
        "model.zip": b"new model",
        "notes.txt": b"mine",
        "summary.json": json.dumps({"policy_steps": 8}, indent=2).encode(),
        "tb/events": b"new events",
    }  # the earlier best model and seed1/ were the earlier run's
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "model.zip",
        "notes.txt",
        "summary.json",
        "tb",
    ]


def test_a_run_interrupted_after_it_finished_is_kept(tmp_path):
    earlier_run(tmp_path)
    with (
        pytest.raises(Interrupted, match="kept the finished run"),
        RunFolder(tmp_path).create(overwrite=True) as run,
    ):
        run.target.write_summary({"new": True})
        run.finish()
        raise KeyboardInterrupt  # e.g. during the training envs' slow shutdown
    assert json.loads((tmp_path / "summary.json").read_text()) == {"new": True}


def killed_while_replacing(folder: Path, phase: str) -> None:
    """What a run killed while taking the earlier run's place leaves in ``folder``."""
    (folder / INCOMING / "tb").mkdir(parents=True)  # the new run's files not moved yet
    (folder / INCOMING / "summary.json").write_text('{"new": true}')
    aside = folder / (REPLACING if phase == "aside" else REPLACED)
    (aside / "seed1").mkdir(parents=True)
    earlier = RunFolder(folder).earlier_run()
    for name in ["model.zip", "seed1/summary.json"] if phase == "aside" else earlier:
        os.replace(folder / name, aside / name)
    if phase == "in":
        (folder / "model.zip").write_bytes(b"new model")  # moved in before the kill


@pytest.mark.parametrize("phase", ["aside", "in"])
def test_what_a_killed_overwrite_left_is_undone_by_the_next_run(tmp_path, phase):
    before = {**earlier_run(tmp_path), "notes.txt": b"mine"}
    killed_while_replacing(tmp_path, phase)
    with pytest.raises(FileExistsError, match="holds an earlier run"):
        RunFolder(tmp_path).create().__enter__()  # refused, but the earlier run put back
    assert contents(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


@pytest.mark.parametrize("phase", ["aside", "in"])
def test_a_refused_train_still_undoes_what_a_killed_overwrite_left(tmp_path, capsys, phase):
    pytest.importorskip("stable_baselines3")
    from elastic_gym.cli import main

    out = tmp_path / "run"
    out.mkdir()
    before = {**earlier_run(out), "notes.txt": b"mine"}
    killed_while_replacing(out, phase)
    with pytest.raises(SystemExit) as stopped:
        main(["train", "--state", "true", "--steps", "8", "--out", str(out)])
    assert stopped.value.code == 2
    assert "holds an earlier run" in capsys.readouterr().err
    assert contents(out) == before  # the earlier run whole again, nothing of the killed one
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".")) == []


# ------------------------------------------------------------------ whole files
@pytest.mark.parametrize("write", ["write_config", "write_summary"])
def test_config_and_summary_are_written_whole_or_not_at_all(tmp_path, monkeypatch, write):
    earlier_run(tmp_path)
    name = "config.yaml" if write == "write_config" else "summary.json"
    before = (tmp_path / name).read_bytes()

    def full_disk(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("elastic_gym.runtime.atomic.os.fsync", full_disk)
    folder = RunFolder(tmp_path)
    argument = TrainConfig(state="true", out_dir=str(tmp_path)) if write == "write_config" else {}
    with pytest.raises(OSError, match="No space left"):
        getattr(folder, write)(argument)
    assert (tmp_path / name).read_bytes() == before  # not truncated
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(f".{name}")]  # no leftover


# ------------------------------------------------------------------ a folder in use
@pytest.mark.parametrize("seeds", [["0"], ["0", "1"]], ids=["one-seed", "seeds"])
def test_a_second_train_into_a_folder_in_use_names_the_process(tmp_path, capsys, seeds):
    pytest.importorskip("stable_baselines3")
    from elastic_gym.cli import main

    out = tmp_path / "run"
    locked = out if len(seeds) == 1 else out / "seed0"  # several seeds: a folder each
    holder = folder_holder(locked, "(out / 'tb').mkdir()")  # a training's first outputs
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(SystemExit) as stopped:
            main(["train", "--state", "true", "--steps", "8", "--out", str(out), "--seeds", *seeds])
        assert stopped.value.code == 2
        err = capsys.readouterr().err
        assert f"is in use by process {holder.pid} " in err and "earlier run" not in err, err
        assert sorted(p.name for p in locked.iterdir()) == [".elastic_gym.lock", "tb"]
    finally:
        holder.kill()
        holder.wait()


# ------------------------------------------------------------------ options before workers
@pytest.mark.parametrize(
    ("options", "named"),
    [
        (["--observer-options", "{omegaa: 100}"], "observer_options.omegaa: unexpected option"),
        (["--residual", "feedforward-state-feedbak"], "action.residual: unknown controller"),
        (
            ["--residual", "motor-pd", "--action-options", "{residual_options: {kpp: 1}}"],
            "action.residual_options.kpp: unexpected option",
        ),
        (["--env-kwargs", "{task_options: {move_tim: 1}}"], "move_tim"),
    ],
    ids=["observer-options", "residual", "residual-options", "env-kwargs"],
)
def test_options_only_a_worker_would_check_are_refused_before_any_starts(
    tmp_path, capsys, options, named
):
    pytest.importorskip("stable_baselines3")
    from elastic_gym.cli import main

    out = tmp_path / "run"
    with pytest.raises(SystemExit) as stopped:
        main(["train", "--steps", "64", "--out", str(out), "--no-progress", *options])
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert named in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert not out.exists()


# ------------------------------------------------------------------ hyper-parameters
@pytest.mark.parametrize(
    ("algo", "key", "value", "interval"),
    [
        ("ppo", "gamma", 1.5, "(0, 1]"),
        ("ppo", "gamma", 0.0, "(0, 1]"),
        ("ppo", "gae_lambda", 1.01, "[0, 1]"),
        ("ppo", "gae_lambda", -0.1, "[0, 1]"),
        ("ppo", "learning_rate", 0.0, "(0, inf)"),
        ("ppo", "learning_rate", -3e-4, "(0, inf)"),
        ("ppo", "clip_range", 0.0, "(0, inf)"),
        ("ppo", "batch_size", 0, "[1, inf)"),
        ("ppo", "n_steps", 0, "[1, inf)"),
        ("ppo", "n_epochs", 0, "[1, inf)"),
        ("ppo", "ent_coef", -0.01, "[0, inf)"),
        ("ppo", "max_grad_norm", 0.0, "(0, inf)"),
        ("recurrentppo", "gamma", 2.0, "(0, 1]"),
        ("sac", "tau", 0.0, "(0, 1]"),
        ("sac", "buffer_size", 0, "[1, inf)"),
        ("sac", "gradient_steps", 0, "[1, inf) or -1"),
        ("td3", "policy_delay", 0, "[1, inf)"),
    ],
)
def test_hyper_parameters_outside_their_meaning_are_refused(algo, key, value, interval):
    config = TrainConfig(algo=algo, state="true", hyperparams={key: value})
    with pytest.raises(ValueError, match=rf"hyper-parameter {key}: must be in \{interval[0]}"):
        config.settings()
    with pytest.raises(ValueError) as refused:
        config.settings()
    assert f"must be in {interval}, got {value!r}" in str(refused.value)


@pytest.mark.parametrize(
    ("algo", "key", "value"),
    [
        ("ppo", "gamma", 1.0),
        ("ppo", "gae_lambda", 0.0),
        ("ppo", "gae_lambda", 1.0),
        ("sac", "gradient_steps", -1),
        ("sac", "learning_starts", 0),
        ("sac", "ent_coef", "auto"),
    ],
)
def test_the_ends_of_the_ranges_and_sb3s_special_values_are_accepted(algo, key, value):
    _, algo_kwargs = TrainConfig(algo=algo, state="true", hyperparams={key: value}).settings()
    assert algo_kwargs[key] == value


def test_an_unknown_key_inside_a_hyper_parameter_files_entry_lists_the_valid_ones(tmp_path):
    path = tmp_path / "hp.yaml"
    path.write_text("default:\n  distill: {iteration: 4}\n")
    config = TrainConfig(algo="recurrentppo", state="sensors", hyperparams_file=str(path))
    with pytest.raises(ValueError, match=r"default\.distill\.iteration: unexpected field") as no:
        config.settings()
    assert "valid: ['iterations', 'episodes', 'steps'," in str(no.value), no.value
    assert "'root'" not in str(no.value)


# ------------------------------------------------------------------ real runs
def tiny(out: Path, **changes) -> TrainConfig:
    """A SAC run of a few policy steps on the true state (seconds)."""
    settings = {
        "algo": "sac",
        "state": "true",
        "total_steps": 30,
        "out_dir": str(out),
        "env_kwargs": {"max_episode_steps": 200},
        "eval_freq": 10**9,
        "hyperparams": {"learning_starts": 10, "batch_size": 8},
    }
    return TrainConfig(**{**settings, **changes})


@pytest.mark.slow
def test_a_run_interrupted_while_its_envs_shut_down_is_complete_and_loads(tmp_path, monkeypatch):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.vec_env import VecNormalize

    from elastic_gym.training import load_run, train

    def interrupted_shutdown(self):
        raise KeyboardInterrupt  # Ctrl-C while the (slow) worker shutdown runs

    monkeypatch.setattr(VecNormalize, "close", interrupted_shutdown)
    out = tmp_path / "run"
    with pytest.raises(Interrupted, match=f"kept the finished run {out}"):
        train(tiny(out), progress_bar=False)
    assert RunFolder(out).finished
    # config.yaml written before the shutdown (our own run folder: trusted)
    assert load_run(out, trust_pickle=True).config.total_steps == 30


@pytest.mark.slow
def test_an_overwrite_interrupted_in_training_keeps_the_earlier_run_loadable(tmp_path, monkeypatch):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import SAC

    from elastic_gym.training import load_run, train

    out = tmp_path / "run"
    train(tiny(out), progress_bar=False)
    before = contents(out)
    learn = SAC.learn

    def interrupted(self, *args, **kwargs):
        learn(self, *args, **kwargs)  # writes tb/ and the learning curve beside
        raise KeyboardInterrupt

    monkeypatch.setattr(SAC, "learn", interrupted)
    with pytest.raises(Interrupted, match=f"kept the earlier run in {out}"):
        train(tiny(out, seed=1), progress_bar=False, overwrite=True)
    assert contents(out) == before
    assert load_run(out, trust_pickle=True).config.seed == 0
    monkeypatch.setattr(SAC, "learn", learn)
    train(tiny(out, seed=1), progress_bar=False, overwrite=True)
    assert load_run(out, trust_pickle=True).config.seed == 1
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".")) == []


def test_an_interrupted_multi_seed_overwrite_settles_each_run(tmp_path):
    """What `train_many` keeps when its workers are stopped: the runs that finished (a
    result, or a new summary in place), each earlier run an unfinished one was replacing
    (its leftovers undone), and nothing of an unfinished run without an earlier one."""
    from elastic_gym.training.train import _settle_runs

    configs = [
        TrainConfig(state="true", seed=s, out_dir=str(tmp_path / f"seed{s}")) for s in range(4)
    ]
    for config in configs:
        Path(config.out_dir).mkdir()
    earlier_run(tmp_path / "seed1")
    before = {**earlier_run(tmp_path / "seed2"), "notes.txt": b"mine"}
    earlier = {c.out_dir: RunFolder(c.out_dir).summary_stamp() for c in configs}
    (tmp_path / "seed0" / "summary.json").write_text("{}")  # seed 0: its result came back
    RunFolder(tmp_path / "seed1").write_summary({"new": True})  # seed 1: in place, no result
    killed_while_replacing(tmp_path / "seed2", "in")  # seed 2: killed while replacing
    (tmp_path / "seed3" / "tb").mkdir()  # seed 3: new, unfinished
    detail = _settle_runs(configs, {0: None}, earlier)
    assert detail == (
        f"kept the finished run(s) {[configs[0].out_dir, configs[1].out_dir]}; removed the "
        f"unfinished run(s) {[configs[3].out_dir]}; kept the earlier run(s) "
        f"{[configs[2].out_dir]} that unfinished runs were to replace"
    )
    assert contents(tmp_path / "seed2") == before
    assert json.loads((tmp_path / "seed1" / "summary.json").read_text()) == {"new": True}
    assert list((tmp_path / "seed3").iterdir()) == []
