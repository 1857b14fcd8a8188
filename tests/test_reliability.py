"""Faults a comparison or a training must survive with nothing lost: user code that exits
or kills its process, a parent killed with SIGKILL, full and read-only disks, a second
writer, hostile YAML, diverging observers."""

from __future__ import annotations

import csv
import errno
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rich.console import Console

from elastic_gym.evaluation import Scenario, ScenarioError, compare

ROOT = Path(__file__).resolve().parents[1]
QUIET = Console(quiet=True)
USER_CODE = '''
import ctypes
import multiprocessing
import os
import sys
import time

import numpy as np

from elastic_gym.controllers.base import Controller


class Faulty(Controller):
    """Zero torque (the excitation task drives the arm); at call ``at`` it does ``fault``
    (``"exit"``, ``"interrupt"``; ``"os_exit"`` and ``"segfault"`` in worker processes
    only, so that the pre-run check in the parent survives); ``delay`` s per call."""

    def __init__(self, model, dt, fault="none", at=3, delay=0.0):
        super().__init__(model, dt)
        self.fault, self.at, self.delay = fault, at, delay

    def reset(self, obs, info):
        self.calls = 0

    def __call__(self, obs, info):
        self.calls += 1
        if self.calls == self.at:
            if self.fault == "exit":
                sys.exit(3)
            if self.fault == "interrupt":
                raise KeyboardInterrupt
            in_worker = multiprocessing.parent_process() is not None
            if self.fault == "os_exit" and in_worker:
                os._exit(7)
            if self.fault == "segfault" and in_worker:
                ctypes.string_at(0)
        time.sleep(self.delay)
        return np.zeros(self.n)


class ExitsWhenBuilt(Faulty):
    def __init__(self, model, dt):
        sys.exit("no licence")
'''


@pytest.fixture
def user_module(tmp_path, monkeypatch):
    """``faulty.py`` importable here and in spawned workers (they inherit sys.path)."""
    (tmp_path / "faulty.py").write_text(USER_CODE)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield "faulty"
    sys.modules.pop("faulty", None)


def faulty_scenario(controllers: dict[str, dict], seeds=(0,), duration=0.05) -> Scenario:
    return Scenario.from_dict(
        {
            "name": "faults",
            "duration": duration,
            "seeds": list(seeds),
            "envs": [{"id": "TwoLinkRigid-v0", "kwargs": {"task": "excitation"}}],
            "controllers": [
                {"name": name, "class": "faulty:Faulty", "options": options}
                for name, options in controllers.items()
            ],
            "state_sources": ["finite-difference"],
        }
    )


def statuses(out: Path) -> dict[tuple[str, str], str]:
    with (out / "runs.csv").open() as handle:
        return {(r["controller"], r["seed"]): r["status"] for r in csv.DictReader(handle)}


# ------------------------------------------------------------ user code that exits
def test_sys_exit_and_a_users_keyboard_interrupt_are_that_runs_failed_row(tmp_path, user_module):
    scenario = faulty_scenario(
        {
            "exits": {"fault": "exit"},
            "interrupts": {"fault": "interrupt"},
            "fine": {},
        },
        seeds=(0, 1),
    )
    out = tmp_path / "out"
    compare(scenario, output_dir=out, workers=1, progress=False, plots=False, console=QUIET)
    found = statuses(out)
    assert len(found) == 6  # the grid went on after each of them
    for seed in ("0", "1"):
        assert found["exits", seed] == "failed: SystemExit: sys.exit(3) called by the run's code"
        assert found["interrupts", seed] == (
            "failed: KeyboardInterrupt: raised by the run's code (no signal)"
        )
        assert found["fine", seed] == "ok"


def test_sys_exit_while_a_controller_is_built_is_refused_before_any_run(tmp_path, user_module):
    scenario = Scenario.from_dict(
        {
            "name": "faults",
            "duration": 0.05,
            "envs": [{"id": "TwoLinkRigid-v0", "kwargs": {"task": "excitation"}}],
            "controllers": [{"name": "x", "class": "faulty:ExitsWhenBuilt"}],
            "state_sources": ["finite-difference"],
        }
    )
    out = tmp_path / "out"
    with pytest.raises(ScenarioError, match=r"controllers\[0\]\.options: SystemExit: sys.exit"):
        compare(scenario, output_dir=out, workers=1, progress=False, console=QUIET)
    assert not out.exists()  # nothing written, not even the folder


# ------------------------------------------------------------ workers that die
def test_a_worker_that_dies_fails_its_own_run_and_the_grid_goes_on(tmp_path, user_module):
    scenario = faulty_scenario(
        {
            "os-exit": {"fault": "os_exit"},
            "segfault": {"fault": "segfault"},
            "exits": {"fault": "exit"},
            "fine": {},
        },
        seeds=(0, 1),
    )
    out = tmp_path / "out"
    result = compare(scenario, output_dir=out, workers=2, progress=False, console=QUIET)
    found = statuses(out)
    assert len(found) == 8 and len(result.runs) == 8
    for seed in ("0", "1"):
        assert found["os-exit", seed] == (
            "failed: WorkerDiedError: its worker process died (exit code 7)"
        )
        assert found["segfault", seed] == (
            "failed: WorkerDiedError: its worker process died (killed by SIGSEGV)"
        )
        assert found["exits", seed].startswith("failed: SystemExit: sys.exit(3)")
        assert found["fine", seed] == "ok"


def test_run_jobs_without_a_crash_handler_names_the_job_whose_worker_died():
    from elastic_gym.parallel import run_jobs

    with pytest.raises(RuntimeError, match=r"^job 2 could not run: WorkerDiedError: .*exit code 5"):
        run_jobs(os_exit_on_two, [0, 1, 2, 3], workers=2, progress=False, describe="job {}".format)


def os_exit_on_two(job: int) -> int:
    if job == 2:
        os._exit(5)
    return job


def processes_with_parent(pid: int) -> list[int]:
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            found.append(int(stat.parent.name))
    return found


def alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def cli(args: list[str], tmp_path: Path, **kwargs) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(tmp_path)])}
    return subprocess.Popen(
        [sys.executable, "-m", "elastic_gym.cli", *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kwargs,
    )


def slow_config(tmp_path: Path, runs: int = 4) -> Path:
    import yaml

    (tmp_path / "faulty.py").write_text(USER_CODE)
    config = tmp_path / "slow.yaml"
    data = faulty_scenario({"slow": {"delay": 0.05}}, seeds=range(runs), duration=2.0).to_dict()
    config.write_text(yaml.safe_dump(data))
    return config


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_workers_end_when_compare_is_killed(tmp_path):
    out = tmp_path / "out"
    args = ["compare", "--config", str(slow_config(tmp_path)), "--output", str(out)]
    process = cli([*args, "--workers", "2", "--no-progress", "--no-plots"], tmp_path)
    deadline = time.monotonic() + 120
    while len(processes_with_parent(process.pid)) < 3:  # 2 workers + the resource tracker
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.1)
    time.sleep(1.0)  # the workers run their first episodes
    left = processes_with_parent(process.pid)
    process.kill()
    process.communicate()
    deadline = time.monotonic() + 5.0
    while any(alive(pid) for pid in left) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not [pid for pid in left if alive(pid)]
