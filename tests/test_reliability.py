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
import signal
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


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_the_ray_runtime_ends_when_compare_is_killed(tmp_path):
    pytest.importorskip("ray")

    def ray_processes() -> list[int]:
        found = []
        for path in Path("/proc").glob("[0-9]*/cmdline"):
            try:
                command = path.read_bytes()
            except OSError:
                continue
            if b"/ray/" in command or command.startswith(b"ray::"):
                found.append(int(path.parent.name))
        return [pid for pid in found if alive(pid)]

    before = set(ray_processes())
    out = tmp_path / "out"
    args = ["compare", "--config", str(slow_config(tmp_path)), "--output", str(out)]
    process = cli([*args, "--workers", "2", "--backend", "ray", "--no-progress"], tmp_path)
    deadline = time.monotonic() + 180
    while not (out / "scenario.yaml").exists() or len(set(ray_processes()) - before) < 5:
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.2)
    time.sleep(3.0)  # the agents and the workers are up
    started = set(ray_processes()) - before
    process.kill()
    process.communicate()
    deadline = time.monotonic() + 15.0
    while any(alive(pid) for pid in started) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [pid for pid in started if alive(pid)]
    for pid in left:  # do not leave them to the other tests
        os.kill(pid, signal.SIGKILL)
    assert not left


# ------------------------------------------------------------ full disks
def rows_of(path: Path) -> list[dict]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def failing_write(monkeypatch, after_bytes: int) -> None:
    """``os.write`` (as the output module calls it) writes ``after_bytes`` bytes more, then
    the disk is full."""
    from elastic_gym.evaluation import output

    budget = [after_bytes]
    real = os.write

    def write(fd: int, data) -> int:
        if budget[0] <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        written = real(fd, bytes(data[: budget[0]]))
        budget[0] -= written
        return written

    monkeypatch.setattr(output.os, "write", write)


def test_runs_csv_keeps_every_complete_row_when_the_disk_fills(tmp_path, monkeypatch):
    from elastic_gym.evaluation.output import ResultsWriteError, RunsCsv

    path = tmp_path / "runs.csv"
    runs = RunsCsv(path)
    for i in range(3):
        runs.add(i, {"run": i, "status": "ok", "track_rms": 0.1 * i})
    failing_write(monkeypatch, after_bytes=7)  # the 4th row is cut off mid-line
    with pytest.raises(
        ResultsWriteError, match=rf"^disk full: 3 of 4 finished rows kept in {path}$"
    ):
        runs.add(3, {"run": 3, "status": "ok", "track_rms": 0.3})
    assert [int(r["run"]) for r in rows_of(path)] == [0, 1, 2]
    assert path.read_text().endswith("\n")
    with pytest.raises(ResultsWriteError, match="3 of 4"):
        runs.finish()  # still refused, the file untouched
    assert [int(r["run"]) for r in rows_of(path)] == [0, 1, 2]


def test_a_new_column_on_a_full_disk_leaves_the_old_file_whole(tmp_path, monkeypatch):
    from elastic_gym.evaluation.output import ResultsWriteError, RunsCsv

    path = tmp_path / "runs.csv"
    runs = RunsCsv(path)
    runs.add(1, {"run": 1, "status": "ok"})
    runs.add(0, {"run": 0, "status": "ok"})
    before = path.read_bytes()
    failing_write(monkeypatch, after_bytes=10)
    with pytest.raises(ResultsWriteError, match="disk full: 2 of 3 finished rows kept"):
        runs.add(2, {"run": 2, "status": "ok", "max_jumps": 4.0})  # the file is rewritten
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["runs.csv"]  # no partial file left


FSIZE_LIMIT = """
import resource, runpy, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes beyond the limit: EFBIG
resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv.pop(1)),) * 2)
sys.argv[0] = "elastic-gym"
runpy.run_module("elastic_gym.cli", run_name="__main__")
"""


def compare_with_file_size_limit(tmp_path: Path, limit: int, out: Path, runs: int):
    import yaml

    (tmp_path / "faulty.py").write_text(USER_CODE)
    config = tmp_path / "grid.yaml"
    data = faulty_scenario({"fine": {}}, seeds=range(runs), duration=0.02).to_dict()
    config.write_text(yaml.safe_dump(data))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(tmp_path)])}
    args = ["compare", "--config", str(config), "--output", str(out), "--workers", "1"]
    return subprocess.run(
        [sys.executable, "-c", FSIZE_LIMIT, str(limit), *args, "--no-progress", "--no-plots"],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_compare_on_a_filling_disk_keeps_its_rows_and_says_so(tmp_path):
    out = tmp_path / "out"
    done = compare_with_file_size_limit(tmp_path, 1200, out, runs=12)
    assert done.returncode == 1, done.stderr
    message = done.stderr.strip().splitlines()[-1]
    assert message.startswith("elastic-gym compare: error: disk full: "), done.stderr
    kept = int(message.split("disk full: ")[1].split()[0])
    assert f"rows kept in {out}/runs.csv" in message
    assert 1 <= kept < 12 and len(rows_of(out / "runs.csv")) == kept
    assert "Traceback" not in done.stderr


def test_a_disk_full_before_the_run_leaves_nothing_that_blocks_a_rerun(tmp_path):
    out = tmp_path / "out"
    done = compare_with_file_size_limit(tmp_path, 50, out, runs=1)
    assert done.returncode == 1, done.stderr
    assert f"disk full: nothing written in {out}/" in done.stderr
    assert not out.exists()
    rerun = compare_with_file_size_limit(tmp_path, 10**7, out, runs=1)
    assert rerun.returncode == 0, rerun.stderr
    assert rows_of(out / "runs.csv")[0]["status"] == "ok"
