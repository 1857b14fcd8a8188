"""RunFolder: a run folder is refused, overwritten or removed exactly as documented, and
nothing else in it is touched."""

from __future__ import annotations

import pytest

from elastic_gym.runtime.parallel import Interrupted
from elastic_gym.training import RunFolder, TrainConfig


def test_a_failed_run_removes_what_it_wrote_and_the_folders_it_made(tmp_path):
    folder = RunFolder(tmp_path / "new" / "run")
    with pytest.raises(RuntimeError, match="boom"), folder.create():
        (folder.path / "model.zip").write_bytes(b"partial")
        (folder.path / "tb").mkdir()
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_clearing_removes_the_temporary_file_of_a_write_a_killed_worker_left(tmp_path):
    """A worker killed outright while writing its config leaves `atomic_file`'s temporary
    file: clearing the unfinished run removes it with the run's files, and leaves a
    user's own files alone."""
    seed = tmp_path / "seed1"
    seed.mkdir()
    (seed / "config.yaml").write_text("env_id: x\n")
    (seed / ".config.yaml.a392gehm.part").write_text("env_")
    RunFolder(tmp_path).clear(keep_folder=True)
    assert list(tmp_path.iterdir()) == []
    seed.mkdir()
    (seed / ".config.yaml.x.part").write_text("")
    (seed / ".notes.part").write_text("mine")
    RunFolder(tmp_path).clear(keep_folder=True)
    assert [p.name for p in seed.iterdir()] == [".notes.part"]


def test_an_earlier_run_is_refused_unless_overwrite_which_replaces_only_its_files(tmp_path):
    (tmp_path / "best_model.zip").write_bytes(b"stale")
    (tmp_path / "notes.txt").write_text("mine")
    (tmp_path / "seed1").mkdir()
    (tmp_path / "seed1" / "summary.json").write_text("{}")
    folder = RunFolder(tmp_path)
    assert folder.earlier_run() == ["best_model.zip", "seed1/summary.json"]
    with pytest.raises(FileExistsError, match="holds an earlier run"), folder.create():
        pass
    assert (tmp_path / "best_model.zip").exists()  # a refusal changes nothing
    with (
        pytest.raises(Interrupted, match="removed the unfinished run; kept the earlier run"),
        folder.create(overwrite=True) as run,
    ):
        assert folder.earlier_run() == ["best_model.zip", "seed1/summary.json"]  # still whole
        (run.target.path / "model.zip").write_bytes(b"partial")
        raise KeyboardInterrupt
    assert folder.earlier_run() == ["best_model.zip", "seed1/summary.json"]
    with folder.create(overwrite=True) as run:
        run.target.write_summary({"policy_steps": 1})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "summary.json"]
    assert folder.finished


def test_a_file_is_not_a_run_folder_and_a_folder_without_a_run_does_not_load(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(NotADirectoryError, match="is a file"):
        RunFolder(tmp_path / "file").check()
    with pytest.raises(ValueError, match="no such folder"):
        RunFolder(tmp_path / "none").read_config()
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "model.zip").write_bytes(b"")
    with pytest.raises(ValueError, match=r"missing \['vecnormalize.pkl', 'config.yaml'\]"):
        RunFolder(tmp_path / "run").read_config()


def test_a_written_config_reads_back_equal(tmp_path):
    config = TrainConfig(
        state="true",
        out_dir=str(tmp_path),
        action={"kind": "torque", "residual_deadzone": 0.1},
        hyperparams={"n_envs": 2},
    )
    folder = RunFolder(tmp_path)
    folder.write_config(config)
    for name in ("model.zip", "vecnormalize.pkl"):
        (tmp_path / name).write_bytes(b"")
    assert folder.read_config() == config
