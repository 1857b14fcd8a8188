"""Faults a comparison or a training must survive with nothing lost: user code that exits
or kills its process, a parent killed with SIGKILL, full and read-only disks, a second
writer, hostile YAML, diverging observers."""

from __future__ import annotations

import contextlib
import csv
import errno
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import (
    alive,
    checkout_env,
    cli_process,
    descendants,
    folder_holder,
    same_metric,
    workers_of,
)
from pool_jobs import os_exit_on_two
from rich.console import Console

from elastic_gym.evaluation import Scenario, ScenarioError, compare

QUIET = Console(quiet=True)
TWO_LINK = "elastic_gym/TwoLinkElastic-v0"
USER_CODE = '''
import ctypes
import os
import signal
import sys
import time

import numpy as np

from elastic_gym.controllers.base import Controller
from elastic_gym.observers.finite_difference import FiniteDifferenceObserver


class Faulty(Controller):
    """Zero torque (the excitation task drives the arm); at call ``at`` (or when built,
    ``when="built"``) it does ``fault``: ``"exit"``, ``"interrupt"``, ``"os_exit"``,
    ``"sigkill"``, ``"segfault"``; ``delay`` s per call."""

    def __init__(self, model, dt, fault="none", at=3, delay=0.0, when="called"):
        super().__init__(model, dt)
        self.fault, self.at, self.delay = fault, at, delay
        if when == "built":
            self.do_fault()

    def do_fault(self):
        if self.fault == "exit":
            sys.exit(3)
        if self.fault == "interrupt":
            raise KeyboardInterrupt
        if self.fault == "os_exit":
            os._exit(7)
        if self.fault == "sigkill":
            os.kill(os.getpid(), signal.SIGKILL)
        if self.fault == "segfault":
            ctypes.string_at(0)

    def reset(self, obs, info):
        self.calls = 0

    def __call__(self, obs, info):
        self.calls += 1
        if self.calls == self.at:
            self.do_fault()
        time.sleep(self.delay)
        return np.zeros(self.n)


class ExitsWhenBuilt(Faulty):
    def __init__(self, model, dt):
        sys.exit("no licence")


class KilledAtReset(FiniteDifferenceObserver):
    def reset(self, obs, initial_estimate=None):
        os.kill(os.getpid(), signal.SIGKILL)


class DivergesAbove(FiniteDifferenceObserver):
    """Finite differences whose estimate turns NaN at the 3rd update of an arm whose first
    encoder reading at the reset exceeds ``threshold``."""

    name = "diverges"

    def __init__(self, model, dt, threshold=0.0):
        super().__init__(model, dt)
        self.threshold = threshold

    def reset(self, obs, initial_estimate=None):
        self.updates, self.diverges = 0, obs["motor_position"][0] > self.threshold
        return super().reset(obs, initial_estimate)

    def update(self, obs, torque, dt):
        self.updates += 1
        estimate = super().update(obs, torque, dt)
        return estimate * np.nan if self.diverges and self.updates >= 3 else estimate
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
@pytest.mark.slow
@pytest.mark.usefixtures("jobs_in_this_process")  # the row is the claim, not the worker
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


@pytest.mark.slow
@pytest.mark.usefixtures("jobs_in_this_process")  # the row is the claim, not the worker
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
@pytest.mark.slow
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


def compare_cli(tmp_path: Path, scenario: Scenario, out: Path, *args: str):
    """``elastic-gym compare`` of ``scenario`` (with ``faulty.py`` importable) into ``out``."""
    import yaml

    (tmp_path / "faulty.py").write_text(USER_CODE)
    config = tmp_path / "grid.yaml"
    config.write_text(yaml.safe_dump(scenario.to_dict()))
    env = checkout_env(tmp_path)
    command = ["compare", "--config", str(config), "--output", str(out), "--no-progress"]
    return subprocess.run(
        [sys.executable, "-m", "elastic_gym.cli", *command, "--no-plots", *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )


@pytest.mark.slow
def test_with_one_worker_user_code_that_ends_its_process_is_that_runs_failed_row(tmp_path):
    """Each fault strikes at the 3rd control period: in the pre-run check's sample of the
    closed loop (left to the runs) and in the run itself; one worker, the CLI default on
    one core."""
    faults = ["os_exit", "sigkill", "segfault", "exit", "interrupt"]
    scenario = faulty_scenario({**{f: {"fault": f} for f in faults}, "fine": {}})
    out = tmp_path / "out"
    done = compare_cli(tmp_path, scenario, out, "--workers", "1")
    assert done.returncode == 1, done.stderr
    assert statuses(out) == {
        ("os_exit", "0"): "failed: WorkerDiedError: its worker process died (exit code 7)",
        ("sigkill", "0"): "failed: WorkerDiedError: its worker process died (killed by SIGKILL)",
        ("segfault", "0"): ("failed: WorkerDiedError: its worker process died (killed by SIGSEGV)"),
        ("exit", "0"): "failed: SystemExit: sys.exit(3) called by the run's code",
        ("interrupt", "0"): "failed: KeyboardInterrupt: raised by the run's code (no signal)",
        ("fine", "0"): "ok",
    }
    assert f"5 of 6 runs failed (status column of {out / 'runs.csv'})" in done.stderr
    assert "5 of 6 runs failed" in (out / "summary.md").read_text()
    assert "Traceback" not in done.stderr


@pytest.mark.slow
@pytest.mark.parametrize(
    ("entry", "message"),
    [
        (
            {
                "controllers": [
                    {
                        "name": "x",
                        "class": "faulty:Faulty",
                        "options": {"fault": "segfault", "when": "built"},
                    }
                ]
            },
            r"controllers\[0\]\.options: WorkerDiedError: its worker process died \(killed "
            r"by SIGSEGV\) while the controller was built",
        ),
        (
            {"state_sources": [{"name": "killed", "class": "faulty:KilledAtReset"}]},
            r"state_sources\[0\]: WorkerDiedError: its worker process died \(killed by "
            r"SIGKILL\) at the reset of the arms and their observer",
        ),
    ],
    ids=["controller-built", "observer-reset"],
)
def test_user_code_that_ends_the_pre_run_checks_process_is_refused_naming_it(
    tmp_path, entry, message
):
    scenario = Scenario.from_dict(
        {
            **faulty_scenario({"fine": {}}).to_dict(),
            **entry,
        }
    )
    out = tmp_path / "out"
    done = compare_cli(tmp_path, scenario, out, "--workers", "1")
    assert done.returncode == 2, done.stderr
    assert re.search(rf"^elastic-gym compare: error: {message}$", done.stderr, re.M), done.stderr
    assert not out.exists()


@pytest.mark.slow
def test_one_worker_runs_in_a_child_unless_the_jobs_need_this_main():
    from elastic_gym.runtime.parallel import run_jobs
    from elastic_gym.runtime.process_pool import refers_to_main

    with pytest.raises(RuntimeError, match=r"^job 2 could not run: WorkerDiedError: .*exit code 5"):
        run_jobs(os_exit_on_two, [0, 1, 2, 3], workers=1, progress=False, describe="job {}".format)
    assert not refers_to_main(os_exit_on_two, [RuntimeError("x"), {"a": np.zeros(2)}])
    assert refers_to_main(type("Scripted", (), {"__module__": "__main__"}))  # a notebook's
    assert refers_to_main(lambda job: job)  # does not pickle: runs here


@pytest.mark.slow
def test_run_jobs_without_a_crash_handler_names_the_job_whose_worker_died():
    from elastic_gym.runtime.parallel import run_jobs

    with pytest.raises(RuntimeError, match=r"^job 2 could not run: WorkerDiedError: .*exit code 5"):
        run_jobs(os_exit_on_two, [0, 1, 2, 3], workers=2, progress=False, describe="job {}".format)


def slow_config(tmp_path: Path, runs: int = 4) -> Path:
    import yaml

    (tmp_path / "faulty.py").write_text(USER_CODE)
    config = tmp_path / "slow.yaml"
    data = faulty_scenario({"slow": {"delay": 0.05}}, seeds=range(runs), duration=2.0).to_dict()
    config.write_text(yaml.safe_dump(data))
    return config


STARTUP_BOUND = 300.0  # s for compare (or Ray) to start its workers on a loaded machine
ENDING_BOUND = 120.0  # s for every worker to end once its parent is gone (polled)
RAY_ENDING_BOUND = 15.0  # s: Ray's orphaned workers end by themselves after ~25 s


def still_alive(pids: list[int], bound: float) -> list[str]:
    """The processes of ``pids`` still alive after polling up to ``bound`` s (killed, so
    that they do not stay for the other tests), as ``"pid (name)"``."""
    deadline = time.monotonic() + bound
    while any(alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = []
    for pid in pids:
        if alive(pid):
            with contextlib.suppress(OSError):
                name = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[0].decode()
                os.kill(pid, signal.SIGKILL)
                left.append(f"{pid} ({name}) alive {bound:.0f} s after its parent was killed")
    return left


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_workers_end_when_compare_is_killed(tmp_path):
    out = tmp_path / "out"
    args = ["compare", "--config", str(slow_config(tmp_path)), "--output", str(out)]
    # its temporary folder here: multiprocessing's pymp-* folder, which a killed process leaves
    env = checkout_env(tmp_path, TMPDIR=str(tmp_path))
    process = cli_process(
        [*args, "--workers", "2", "--no-progress", "--no-plots"], tmp_path, env=env
    )
    started = time.monotonic()
    while len(workers_of(process.pid)) < 2:
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < started + STARTUP_BOUND, f"no workers after {STARTUP_BOUND} s"
        time.sleep(0.1)
    time.sleep(1.0)  # the workers run their first episodes
    left = descendants(process.pid)  # the workers, their fork server, the resource tracker
    process.kill()
    process.communicate()
    assert not still_alive(left, ENDING_BOUND)


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_the_ray_runtime_ends_when_compare_is_killed(tmp_path):
    pytest.importorskip("ray")
    from elastic_gym.runtime.orphan_reaper import ray_descendants

    out = tmp_path / "out"
    args = ["compare", "--config", str(slow_config(tmp_path)), "--output", str(out)]
    process = cli_process([*args, "--workers", "2", "--backend", "ray", "--no-progress"], tmp_path)
    deadline = time.monotonic() + STARTUP_BOUND
    agents = {b"ray::DashboardAgent", b"ray::RuntimeEnvAgent"}  # what used to stay

    def names(pids) -> set[bytes]:
        found = set()
        for pid in pids:
            with contextlib.suppress(OSError):
                argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
                found.add(b" ".join(argv[:2]).strip())  # a worker: python .../default_worker.py
        return found

    def workers(names: set[bytes]) -> set[bytes]:  # starting, or named after their task
        return {n for n in names if b"/workers/" in n or n in (b"ray::IDLE", b"ray::_call")}

    started: dict[int, int] = {}
    while not (agents <= names(started) and workers(names(started))):  # Ray is up
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline, f"Ray not up after {STARTUP_BOUND} s"
        time.sleep(0.05)
        started = ray_descendants(process.pid)  # GCS, raylet, agents, workers
    process.kill()  # while its workers start: the raylet dies with it, they do not
    process.communicate()
    # the reaper waits for the parent to be gone, then freezes and kills in rounds
    assert not still_alive(list(started), RAY_ENDING_BOUND)


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
from elastic_gym.cli import main
# the same comparison first, elsewhere: numba's cache files (written on a first compile
# of every kernel the batched loop uses) are not what is tested
warm = sys.argv[2:]
warm[warm.index("--output") + 1] += "-warm"
assert main(warm) == 0
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes beyond the limit: EFBIG
resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv.pop(1)),) * 2)
sys.argv[0] = "elastic-gym"
runpy.run_module("elastic_gym.cli", run_name="__main__")
"""


def fine_compare_args(tmp_path: Path, out: Path, runs: int) -> list[str]:
    """``elastic-gym compare`` arguments of ``runs`` seeds of a fine controller into ``out``
    (its config and ``faulty.py`` written in ``tmp_path``)."""
    import yaml

    (tmp_path / "faulty.py").write_text(USER_CODE)
    config = tmp_path / "grid.yaml"
    data = faulty_scenario({"fine": {}}, seeds=range(runs), duration=0.02).to_dict()
    config.write_text(yaml.safe_dump(data))
    args = ["compare", "--config", str(config), "--output", str(out), "--workers", "1"]
    return [*args, "--no-progress", "--no-plots"]


def compare_with_file_size_limit(tmp_path: Path, limit: int, out: Path, runs: int):
    return subprocess.run(
        [sys.executable, "-c", FSIZE_LIMIT, str(limit), *fine_compare_args(tmp_path, out, runs)],
        env=checkout_env(tmp_path),
        capture_output=True,
        text=True,
        timeout=900,
    )


@pytest.mark.slow
def test_compare_on_a_filling_disk_keeps_its_rows_and_says_so(tmp_path):
    out = tmp_path / "out"
    done = compare_with_file_size_limit(tmp_path, 1200, out, runs=12)
    assert done.returncode == 1, done.stderr
    said = [line for line in done.stderr.splitlines() if "compare: error: disk full: " in line]
    assert said, done.stderr
    message = said[-1]
    kept = int(message.split("disk full: ")[1].split()[0])
    assert f"rows kept in {out}/runs.csv" in message
    assert 1 <= kept < 12 and len(rows_of(out / "runs.csv")) == kept
    assert "Traceback" not in done.stderr


@pytest.mark.slow
def test_a_disk_full_before_the_run_leaves_nothing_that_blocks_a_rerun(tmp_path, user_module):
    from elastic_gym.cli import main

    out = tmp_path / "out"
    done = compare_with_file_size_limit(tmp_path, 50, out, runs=1)
    assert done.returncode == 1, done.stderr
    assert f"disk full: nothing written in {out}/" in done.stderr
    assert not out.exists()
    assert main(fine_compare_args(tmp_path, out, runs=1)) == 0  # the rerun, in this process
    assert rows_of(out / "runs.csv")[0]["status"] == "ok"


# ------------------------------------------------------------ a second writer
def test_a_second_writer_of_an_output_folder_is_refused_with_the_holders_pid(tmp_path):
    from elastic_gym.runtime.folder_lock import LOCK_FILE, FolderLockedError, folder_lock

    folder = tmp_path / "out"
    holder = folder_holder(folder)
    try:
        assert holder.stdout.readline().strip() == "locked"
        locked = pytest.raises(FolderLockedError, match=rf"in use by process {holder.pid} ")
        with locked, folder_lock(folder):
            pass
        scenario = faulty_scenario({"fine": {}})
        with pytest.raises(FolderLockedError, match=str(folder)):
            compare(scenario, output_dir=folder, workers=1, progress=False, console=QUIET)
        assert sorted(p.name for p in folder.iterdir()) == [LOCK_FILE]  # nothing written
    finally:
        holder.kill()  # SIGKILL: the kernel drops its lock
        holder.wait()
    assert (folder / LOCK_FILE).exists()  # a killed holder cannot remove its lock file
    with folder_lock(folder):  # but it does not block the next one
        pass
    assert list(folder.iterdir()) == []


def test_train_refuses_a_run_folder_that_another_training_writes(tmp_path):
    pytest.importorskip("stable_baselines3")
    from elastic_gym.cli import main
    from elastic_gym.runtime.folder_lock import folder_lock

    out = tmp_path / "run"
    with folder_lock(out), pytest.raises(SystemExit) as stopped:
        main(["train", "--state", "true", "--steps", "8", "--out", str(out), "--no-progress"])
    assert stopped.value.code == 2
    assert not out.exists()


def test_train_on_a_read_only_folder_is_refused_before_building_anything(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    from elastic_gym.cli import main

    if os.geteuid() == 0:
        if not os.path.isdir("/sys"):
            pytest.skip("no read-only folder to test with")
        out = Path("/sys/elastic-gym-run")  # sysfs refuses new files, even to root
    else:
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        out = locked / "run"
    start = time.monotonic()
    with pytest.raises(SystemExit) as stopped:
        main(["train", "--state", "true", "--steps", "8", "--out", str(out), "--no-progress"])
    assert stopped.value.code == 2
    assert "cannot write in" in capsys.readouterr().err
    assert time.monotonic() - start < 5.0  # no env, no model built


# ------------------------------------------------------------ unbounded episodes, big batches
@contextlib.contextmanager
def failing_after(seconds: float):
    """Fail the test (not hang it) if the block runs longer than ``seconds`` (SIGALRM)."""

    def expired(signum, frame):
        pytest.fail(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def test_training_with_episodes_that_never_end_is_refused_not_hung(tmp_path, capsys):
    """In this process (the exit codes of a real ``elastic-gym`` process are those of
    ``main``: the compare tests above run it as one)."""
    pytest.importorskip("stable_baselines3")
    from elastic_gym.cli import main

    out = tmp_path / "run"
    args = ["train", "--state", "true", "--steps", "64", "--out", str(out), "--no-progress"]
    with failing_after(240.0), pytest.raises(SystemExit) as stopped:
        main([*args, "--env-kwargs", "{episode_time: null}"])
    assert stopped.value.code == 2
    assert "env_kwargs.episode_time: None (episodes that never end)" in capsys.readouterr().err
    assert not out.exists()


def urdf_of(env_id: str) -> str:
    from elastic_gym.evaluation.grid import env_robot

    return env_robot(f"elastic_gym/{env_id}", {}).urdf


def test_a_batch_too_large_for_the_memory_is_refused_before_it_is_built(monkeypatch):
    import gymnasium as gym

    from elastic_gym.envs import memory

    start = time.monotonic()
    with pytest.raises(ValueError, match=r"n_arms=100000000: a batch of 100000000 .* GiB"):
        gym.make_vec(
            "elastic_gym/TwoLinkElastic-v0", 10**8, vectorization_mode="vector_entry_point"
        )
    assert time.monotonic() - start < 5.0
    monkeypatch.setattr(memory, "available_bytes", lambda: 1024**3)  # a 1 GiB machine
    needed = memory.batch_bytes(urdf_of("TwoLinkElastic-v0"), 20_000) / 1024**3
    with pytest.raises(ValueError, match=rf"needs about {needed:.1f} GiB .* and 1.0 GiB"):
        gym.make_vec(
            "elastic_gym/TwoLinkElastic-v0", 20_000, vectorization_mode="vector_entry_point"
        )
    # the estimate is linear in the arms and counts each byte of mesh MESH_FACTOR times
    urdf = urdf_of("IiwaElastic-v0")
    assert memory.mesh_bytes(urdf) > 0
    assert memory.batch_bytes(urdf, 7) == 7 * (
        memory.ARM_BYTES + memory.MESH_FACTOR * memory.mesh_bytes(urdf)
    )


# ------------------------------------------------------------ diverging observers
EKF_DIVERGED = (
    "observer 'ekf' (ExtendedKalmanFilter): non-finite theta, q, dtheta, dq after an update"
)


def test_a_diverging_ekf_ends_its_episode_with_the_documented_reason():
    import gymnasium as gym

    from elastic_gym.observers.wrappers import ObserverWrapper

    env = ObserverWrapper(gym.make(TWO_LINK), "ekf", initial_estimate=np.full(8, 1e300))
    obs, _ = env.reset(seed=0)
    with np.errstate(all="ignore"):
        obs, _, terminated, truncated, info = env.step(np.zeros(2))
    assert terminated and not truncated
    assert info["termination_reason"] == "non-finite state estimate"
    assert info["observer_error"] == EKF_DIVERGED
    assert np.array_equal(obs["state"], np.full(8, 1e300))  # the last finite estimate
    with pytest.raises(RuntimeError, match="call reset"):
        env.step(np.zeros(2))
    obs, _ = env.reset(seed=0)  # a reset starts afresh
    env.close()


def test_one_diverging_arm_of_a_vector_env_ends_alone_the_others_bit_for_bit():
    import gymnasium as gym

    from elastic_gym.observers import vector
    from elastic_gym.observers.wrappers import ObserverWrapper

    initial = np.zeros((3, 8))
    initial[1] = 1e300
    envs = vector.ObserverWrapper(
        gym.make_vec(TWO_LINK, 3, vectorization_mode="vector_entry_point"), "ekf", initial
    )
    singles = [
        ObserverWrapper(gym.make(TWO_LINK), "ekf", initial_estimate=np.zeros(8)) for _ in "ab"
    ]
    obs, _ = envs.reset(seed=10)
    for single, seed in zip(singles, (10, 12), strict=True):
        single.reset(seed=seed)
    with np.errstate(all="ignore"):
        for step in range(4):
            obs, _, terminated, _, info = envs.step(np.zeros((3, 2)))
            assert terminated.tolist() == [False, step % 2 == 0, False]  # ends after each reset
            assert info["termination_reason"][1] == (
                "non-finite state estimate" if step % 2 == 0 else None
            )
            if step % 2 == 0:  # the single env's text (its N = 1 case, tested above)
                assert info["observer_error"].tolist() == [None, EKF_DIVERGED, None]
            else:
                assert "observer_error" not in info
            for single, arm in zip(singles, (0, 2), strict=True):
                single_obs, *_ = single.step(np.zeros(2))
                assert np.array_equal(obs["state"][arm], single_obs["state"])
    envs.close()


@pytest.mark.parametrize(
    ("error", "ends"),
    [
        (np.linalg.LinAlgError("the covariance is not positive definite"), True),
        (ValueError("array must not contain infs or NaNs"), True),  # scipy's check_finite
        (FloatingPointError("overflow encountered in multiply"), True),
        (ZeroDivisionError("division by zero"), False),  # a bug: the run fails
    ],
)
def test_a_numerical_failure_in_an_observer_update_ends_the_episode(error, ends):
    import gymnasium as gym

    from elastic_gym.observers.finite_difference import FiniteDifferenceObserver
    from elastic_gym.observers.wrappers import ObserverWrapper

    class Failing(FiniteDifferenceObserver):
        name = "failing"

        def update(self, obs, torque, dt):
            raise error

    rigid = gym.make("elastic_gym/TwoLinkRigid-v0")
    env = ObserverWrapper(rigid, Failing(rigid.unwrapped.model, rigid.unwrapped.control_dt))
    env.reset(seed=0)
    if not ends:
        with pytest.raises(ZeroDivisionError):
            env.step(np.zeros(2))
        return
    _, _, terminated, _, info = env.step(np.zeros(2))
    assert terminated and info["termination_reason"] == "non-finite state estimate"
    assert info["observer_error"] == f"{type(error).__name__}: {error}"


@pytest.mark.parametrize(
    ("returned", "error", "message"),
    [
        (
            lambda x: list(x),
            TypeError,
            r"update returned a list, expected a numpy array of shape \(4,\)",
        ),
        (
            lambda x: x[:3],
            ValueError,
            r"update returned an estimate of shape \(3,\), expected \(4,\)",
        ),
    ],
)
def test_an_observer_returning_the_wrong_thing_is_named(returned, error, message):
    import gymnasium as gym

    from elastic_gym.observers.finite_difference import FiniteDifferenceObserver
    from elastic_gym.observers.wrappers import ObserverWrapper

    class Sloppy(FiniteDifferenceObserver):
        name = "sloppy"

        def update(self, obs, torque, dt):
            return returned(super().update(obs, torque, dt))

    rigid = gym.make("elastic_gym/TwoLinkRigid-v0")
    env = ObserverWrapper(rigid, Sloppy(rigid.unwrapped.model, rigid.unwrapped.control_dt))
    env.reset(seed=0)
    with pytest.raises(error, match=rf"^observer 'sloppy' \(Sloppy\): {message}"):
        env.step(np.zeros(2))


@pytest.mark.slow
@pytest.mark.usefixtures("jobs_in_this_process")  # the row is the claim, not the worker
def test_a_diverging_ekf_in_compare_is_a_terminated_row_not_a_failure(tmp_path):
    scenario = Scenario.from_dict(
        {
            "name": "diverging",
            "duration": 0.02,
            "envs": [{"id": "TwoLinkElastic-v0"}],
            "controllers": ["motor-pd"],
            "state_sources": [{"name": "ekf", "initial_estimate": [1e300] * 8}],
        }
    )
    result = compare(scenario, output_dir=tmp_path, workers=1, progress=False, console=QUIET)
    assert result.runs["status"].tolist() == [
        f"terminated: non-finite state estimate ({EKF_DIVERGED})"
    ]


@pytest.mark.slow
@pytest.mark.usefixtures("jobs_in_this_process")  # the row is the claim, not the worker
def test_a_diverging_arm_of_a_batched_comparison_is_its_terminated_row_with_the_reason(
    tmp_path, user_module
):
    """Seed 0 is the one of the three whose first encoder reading exceeds the threshold;
    its batch mates' rows equal their rows in worlds of their own."""
    import gymnasium as gym

    seeds, threshold = [2, 0, 3], -0.75
    first = {seed: gym.make(TWO_LINK, physics_dt=6.25e-5).reset(seed=seed)[0] for seed in seeds}
    assert [s for s in seeds if first[s]["motor_position"][0] > threshold] == [0]
    scenario = Scenario.from_dict(
        {
            "name": "diverging-arm",
            "duration": 0.01,
            "seeds": seeds,
            "envs": ["TwoLinkElastic-v0"],
            "controllers": ["motor-pd"],
            "state_sources": [
                {
                    "name": "diverges",
                    "class": "faulty:DivergesAbove",
                    "options": {"threshold": threshold},
                }
            ],
        }
    )
    rows = {}
    for batch_size in (1, 8):
        rows[batch_size] = compare(
            scenario,
            output_dir=tmp_path / str(batch_size),
            workers=1,
            progress=False,
            plots=False,
            console=QUIET,
            batch_size=batch_size,
        ).runs.to_dict("records")
    batched = {row["seed"]: row for row in rows[8]}
    assert batched[0]["status"] == (
        "terminated: non-finite state estimate (observer 'diverges' (DivergesAbove): "
        "non-finite theta, q, dtheta, dq after an update)"
    )
    assert batched[0]["sim_time"] == pytest.approx(2e-3)  # recorded until it diverged
    assert batched[2]["status"] == batched[3]["status"] == "ok"
    for alone in rows[1]:
        row = batched[alone["seed"]]
        differ = {k: (alone[k], row[k]) for k in alone if k != "sim_wall_ratio"}
        assert all(same_metric(*pair) for pair in differ.values()), alone["seed"]


# ------------------------------------------------------------ sensors and numbers
def test_an_accelerometer_range_below_g_is_refused_and_saturation_is_flagged():
    import gymnasium as gym

    with pytest.raises(ValueError, match=r"accelerometer\.range: .*must be .*at least g"):
        gym.make(TWO_LINK, accelerometer={"range": 5.0})
    env = gym.make(TWO_LINK, accelerometer={"range": 9.81, "noise_density": np.float32(1e-3)})
    _, info = env.reset(seed=0)
    saturated = [info["acceleration_saturated"]]
    for _ in range(20):
        obs, *_, info = env.step(np.full(2, 1e3))  # clipped to the torque limits
        saturated.append(info["acceleration_saturated"])
        assert saturated[-1] == bool(np.any(np.abs(obs["acceleration"]) >= 9.81))
    assert any(saturated)
    _, info = gym.make(TWO_LINK).reset(seed=0)
    assert info["acceleration_saturated"] is False


def test_numpy_scalars_are_accepted_wherever_python_numbers_are():
    import gymnasium as gym

    from elastic_gym.training import TrainConfig

    env = gym.make(TWO_LINK, encoder={"resolution": np.float32(0.001)})
    assert env.unwrapped.batch.encoder.resolution == pytest.approx(0.001)
    with pytest.raises(
        ValueError, match=r"^eval_episodes: Input should be greater than or equal to 1, got 0$"
    ):
        TrainConfig(eval_episodes=0)
    assert TrainConfig(eval_episodes=np.int64(2)).eval_episodes == 2


def test_a_refused_reset_changes_no_random_stream():
    import gymnasium as gym

    def streams(env) -> list:
        return [rng.bit_generator.state for rng in env.unwrapped.batch.rngs]

    envs = gym.make_vec(TWO_LINK, 3, vectorization_mode="vector_entry_point")
    envs.reset(seed=5)
    before = streams(envs)
    refused = [
        ({"seed": 1.5}, TypeError, "seed must be an integer >= 0, a list of 3"),
        ({"seed": [7, 8, -1]}, ValueError, r"seed\[2\] must be an integer >= 0, got -1"),
        ({"seed": 9, "options": {"bogus": 1}}, ValueError, "options.bogus: unexpected field"),
    ]
    for kwargs, error, message in refused:
        with pytest.raises(error, match=message):
            envs.reset(**kwargs)
        assert streams(envs) == before
    env = gym.make(TWO_LINK)
    env.reset(seed=3)
    before = streams(env)
    with pytest.raises(ValueError, match=r"options\.bogus: unexpected field"):
        env.reset(seed=4, options={"bogus": 1})
    assert streams(env) == before and env.unwrapped.np_random is env.unwrapped.batch.rngs[0]


@pytest.mark.slow
@pytest.mark.usefixtures("jobs_in_this_process")  # the row is the claim, not the worker
def test_a_duration_below_the_control_period_is_refused(tmp_path, user_module):
    scenario = faulty_scenario({"fine": {}}, duration=0.0004)
    with pytest.raises(ScenarioError, match=r"^duration: 0\.0004 s is shorter than the control"):
        compare(scenario, output_dir=tmp_path / "out", workers=1, progress=False, console=QUIET)
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------ hostile YAML
BOMB = "".join(
    f"{name}: &{name} [{', '.join([f'*{prev}'] * 9) if prev else ', '.join(['lol'] * 9)}]\n"
    for prev, name in zip(["", "a", "b", "c", "d", "e", "f"], "abcdefg", strict=True)
)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("name: x\nname: y\n", r"scn\.yaml: top level: duplicate key 'name' \(lines 1 and 2\)"),
        (
            "envs:\n  - id: TwoLinkRigid-v0\n    kwargs: {task: a, task: b}\n",
            r"scn\.yaml: envs\[0\]\.kwargs: duplicate key 'task'",
        ),
        ("x: " + "[" * 20000 + "]" * 20000, r"scn\.yaml: invalid YAML: nesting deeper than 64"),
        (BOMB, r"scn\.yaml: f: expands \(through its aliases\) to more than 100000 values"),
        ("a: &a [*a]\n", r"scn\.yaml: a\[0\]: an alias refers to the node that contains it"),
    ],
)
def test_hostile_scenario_yaml_is_refused_with_file_and_field(tmp_path, text, message):
    from elastic_gym.evaluation import load_scenario

    path = tmp_path / "scn.yaml"
    path.write_text(text)
    with pytest.raises(ScenarioError, match=rf"^{tmp_path}/{message}"):
        load_scenario(path)


def test_yaml_larger_than_the_bound_is_refused(tmp_path):
    from elastic_gym.yaml_io import MAX_BYTES, YAMLInputError, load_yaml

    path = tmp_path / "big.yaml"
    path.write_text("x: " + "a" * MAX_BYTES)
    with pytest.raises(YAMLInputError, match=rf"big\.yaml: larger than {MAX_BYTES} bytes"):
        load_yaml(path)
    assert load_yaml("a: 1\nb: [1, 2]\n", "--env-kwargs") == {"a": 1, "b": [1, 2]}
    with pytest.raises(YAMLInputError, match=r"^--env-kwargs: top level: duplicate key 'a'"):
        load_yaml("{a: 1, a: 2}", "--env-kwargs")


@pytest.mark.parametrize(
    ("module_text", "cls", "message"),
    [
        ("value = 3\n", "m:value", r"'m:value' is not a class but int 3"),
        ("def broken(:\n", "m:X", r"importing module 'm' failed: SyntaxError: "),
        (
            "raise RuntimeError('no licence server')\n",
            "m:X",
            r"importing module 'm' failed: RuntimeError: no",
        ),
        ("import sys\nsys.exit(4)\n", "m:X", r"importing module 'm' failed: SystemExit: 4"),
    ],
)
def test_a_class_entry_that_cannot_be_imported_names_the_field_and_module(
    tmp_path, monkeypatch, module_text, cls, message
):
    (tmp_path / "m.py").write_text(module_text)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "m", raising=False)
    scenario = Scenario.from_dict(
        {
            "name": "imports",
            "duration": 0.02,
            "envs": [{"id": "TwoLinkRigid-v0"}],
            "controllers": [{"name": "mine", "class": cls}],
            "state_sources": ["finite-difference"],
        }
    )
    with pytest.raises(ScenarioError, match=rf"^controllers\[0\]\.class: {message}"):
        compare(scenario, output_dir=tmp_path / "out", workers=1, progress=False, console=QUIET)


# ------------------------------------------------------------ run folders
@pytest.mark.slow
@pytest.mark.usefixtures("jobs_in_this_process")  # the row is the claim, not the worker
def test_a_run_folder_whose_config_no_longer_matches_its_model_is_refused_before_any_run(
    tmp_path, single_thread_torch
):
    pytest.importorskip("stable_baselines3")
    import yaml

    from elastic_gym.training import TrainConfig, train

    run = tmp_path / "run"
    hyperparams = {"n_envs": 1, "n_steps": 32, "batch_size": 32, "n_epochs": 1}
    config = TrainConfig(
        env_id="TwoLinkRigid-v0",
        algo="ppo",
        state="true",
        total_steps=32,
        out_dir=str(run),
        env_kwargs={"max_episode_steps": 20},
        hyperparams=hyperparams,
        eval_freq=10**6,
        eval_episodes=1,
    )
    train(config, progress_bar=False)
    data = yaml.safe_load((run / "config.yaml").read_text())
    data["env_id"] = "elastic_gym/TwoLinkElastic-v0"  # a config.yaml copied from another run
    (run / "config.yaml").write_text(yaml.safe_dump(data))
    scenario = Scenario.from_dict(
        {
            "name": "policy",
            "duration": 0.02,
            "envs": [{"id": "TwoLinkElastic-v0"}],
            "controllers": [
                {"name": "trained-policy", "options": {"run": str(run), "trust_pickle": True}}
            ],
            "state_sources": ["true"],
        }
    )
    out = tmp_path / "out"
    with pytest.raises(
        ScenarioError,
        match=r"^controllers\[0\]\.options: ValueError: .*model\.zip takes observations of "
        r"shape \(\d+,\), but config\.yaml \(elastic_gym/TwoLinkElastic-v0, state 'true'\) "
        r"gives \d+ entries",
    ):
        compare(scenario, output_dir=out, workers=1, progress=False, console=QUIET)
    assert not out.exists()
    on_the_trained_robot = Scenario.from_dict({**scenario.to_dict(), "envs": ["TwoLinkRigid-v0"]})
    with pytest.raises(
        ScenarioError,
        match=r"config\.yaml says the policy was trained on elastic_gym/TwoLinkElastic-v0 "
        r"\(robot 'two_link_elastic'\); the comparison runs it on the robot 'two_link_rigid'",
    ):
        compare(on_the_trained_robot, output_dir=out, workers=1, progress=False, console=QUIET)


# ------------------------------------------------------------ recording a video
@pytest.mark.slow
def test_record_video_writes_every_frame_of_an_episode(tmp_path):
    pytest.importorskip("moviepy")
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
    import gymnasium as gym
    from gymnasium.wrappers import RecordVideo

    env = gym.make(TWO_LINK, render_mode="rgb_array", episode_time=0.02)
    env.reset(seed=0)
    height, width, _ = env.render().shape
    folder = tmp_path / "videos"  # a new folder: RecordVideo warns when it overwrites one
    env = RecordVideo(env, str(folder), episode_trigger=lambda _: True, disable_logger=True)
    env.reset(seed=0)
    steps = 0
    while True:
        steps += 1
        _, _, terminated, truncated, _ = env.step(np.zeros(2))
        if terminated or truncated:
            break
    env.close()
    video = folder / "rl-video-episode-0.mp4"
    frames, _ = imageio_ffmpeg.count_frames_and_secs(str(video))
    assert steps == 20 and frames == steps + 1  # the reset's frame and one per step
    reader = imageio_ffmpeg.read_frames(str(video))
    assert next(reader)["size"] == (width, height)
    reader.close()
