"""SIGINT / SIGTERM during `elastic-gym compare --workers 2` and `elastic-gym train --seeds ...`:
the command stops within seconds, keeps the finished runs on disk, ends its worker
processes (none is left behind) and exits with 128 + the signal number."""

from __future__ import annotations

import csv
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from helpers import alive, cli_process, descendants, workers_of

SLEEPY_CONTROLLER = '''
import time

import numpy as np

from elastic_gym.controllers.base import Controller


class Sleepy(Controller):
    """Zero action (the excitation task drives the arm), ``delay`` s of wall time per step."""

    name = "sleepy"

    def __init__(self, model, dt, delay):
        super().__init__(model, dt)
        self.delay = delay

    def __call__(self, obs, info):
        time.sleep(self.delay)
        return np.zeros(self.n)
'''
N_RUNS = 8  # 4 seeds x (a fast controller, and one taking 20 s per run)
STOP_TIME = 4.0  # s until the workers are gone: the runs in flight would take far longer
EXIT_TIME = 30.0  # s until the command has exited (a loaded machine slows its teardown)


def wait_for(condition, process: subprocess.Popen, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if process.poll() is not None:
            out, err = process.communicate()
            pytest.fail(f"the command ended first ({process.returncode}): {out}\n{err}")
        if time.monotonic() > deadline:
            process.kill()
            pytest.fail("timed out waiting for the first finished run")
        time.sleep(0.05)


def data_rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with path.open() as handle:
        return list(csv.DictReader(handle))


def stop(process: subprocess.Popen, signum: int) -> tuple[float, str]:
    """Send ``signum``; return the time until its worker processes are gone, and its
    stderr once it has exited (no process it started may be left behind: workers, their
    fork server, the resource tracker)."""
    descendants_before = descendants(process.pid)
    workers = workers_of(process.pid)
    assert len(workers) >= 2
    process.send_signal(signum)
    sent = time.monotonic()
    while any(alive(pid) for pid in workers) and time.monotonic() < sent + EXIT_TIME:
        time.sleep(0.02)
    workers_gone = time.monotonic() - sent
    _, err = process.communicate(timeout=EXIT_TIME)
    deadline = time.monotonic() + 5.0
    while any(alive(pid) for pid in descendants_before) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not [pid for pid in descendants_before if alive(pid)]
    return workers_gone, err


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_interrupted_compare_keeps_finished_runs_and_ends_its_workers(tmp_path, signum):
    (tmp_path / "sleepy_controller.py").write_text(SLEEPY_CONTROLLER)
    config = tmp_path / "slow.yaml"
    config.write_text(
        yaml.safe_dump(
            {
                "name": "slow",
                "duration": 0.4,
                "seeds": list(range(N_RUNS // 2)),
                "envs": [{"id": "TwoLinkRigid-v0", "kwargs": {"task": "excitation"}}],
                "controllers": [
                    {
                        "name": "fast",
                        "class": "sleepy_controller:Sleepy",
                        "options": {"delay": 0.0},
                    },
                    {
                        "name": "slow",
                        "class": "sleepy_controller:Sleepy",
                        "options": {"delay": 0.05},
                    },
                ],
                "state_sources": ["finite-difference"],
            }
        )
    )
    out = tmp_path / "out"
    process = cli_process(
        [
            "compare",
            "--config",
            str(config),
            "--output",
            str(out),
            "--workers",
            "2",
            "--no-progress",
            "--no-plots",
        ],
        tmp_path,
    )
    wait_for(lambda: data_rows(out / "runs.csv"), process, timeout=180)
    workers_gone, err = stop(process, signum)

    assert process.returncode == 128 + signum, err
    assert workers_gone < STOP_TIME
    rows = data_rows(out / "runs.csv")
    assert 1 <= len(rows) < N_RUNS and {row["status"] for row in rows} == {"ok"}
    assert {row["controller"] for row in rows} == {"fast"}
    name = signal.Signals(signum).name
    assert f"interrupted by {name}: kept the {len(rows)} finished of {N_RUNS} runs" in err
    assert "Interrupted: kept" in (out / "summary.md").read_text()
    assert len(data_rows(out / "summary.csv")) == 1


@pytest.mark.slow
def test_interrupted_multi_seed_training_keeps_finished_runs_and_ends_its_workers(tmp_path):
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "runs"
    process = cli_process(
        [
            "train",
            "--algo",
            "sac",
            "--state",
            "true",
            "--steps",
            "60",
            "--seeds",
            "0",
            "1",
            "2",
            "--workers",
            "2",
            "--out",
            str(out),
            "--env-kwargs",
            "{max_episode_steps: 100}",
            "--hyperparams",
            "learning_starts=20",
            "batch_size=16",
            "--eval-freq",
            "1000000",
            "--no-progress",
        ],
        tmp_path,
    )
    wait_for(lambda: list(out.glob("seed*/summary.json")), process, timeout=300)
    workers_gone, err = stop(process, signal.SIGINT)

    assert process.returncode == 130, err
    assert workers_gone < STOP_TIME  # the queued and running seeds would take far longer
    assert "interrupted by SIGINT: kept the finished run(s)" in err
    finished = sorted(p.parent.name for p in out.glob("seed*/summary.json"))
    assert finished and "seed2" not in finished
    for folder in out.iterdir():  # an unfinished run leaves nothing behind
        assert folder.name in finished, sorted(p.name for p in folder.iterdir())
        assert (folder / "model.zip").exists() and str(folder) in err
