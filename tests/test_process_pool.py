"""The worker pool: one set of processes serves several calls (the pre-run check and
the runs of a comparison), a call left early never hands its results to the next, and a
worker forked from a fork server sees what a spawned one would."""

from __future__ import annotations

import importlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import alive, checkout_env, descendants, workers_of
from pool_jobs import PidLog, pid_of, slow_square, what_a_job_sees
from rich.console import Console

from elastic_gym.evaluation import Scenario, compare
from elastic_gym.runtime import fork_server
from elastic_gym.runtime.parallel import worker_processes


@pytest.mark.slow
def test_one_pool_runs_two_functions_in_the_same_processes():
    with worker_processes(2) as pool:
        first = {pid for _, ok, (_, pid) in pool.results(pid_of, list(range(8))) if ok}
        squares = {index: value for index, _, value in pool.results(slow_square, [3, 1, 2])}
        second = {pid for _, _, (_, pid) in pool.results(pid_of, list(range(8)), workers=1)}
    assert squares == {0: 9, 1: 1, 2: 4}
    assert len(first) == 2 and os.getpid() not in first
    assert len(second) == 1 and second <= first  # workers=1: one of the same processes


@pytest.mark.slow
def test_a_worker_sees_the_environment_folder_and_output_of_its_own_start(tmp_path, monkeypatch):
    """As a spawned process would: the environment (and BLAS threads), working folder and
    standard output of the moment the worker starts, not those of its fork server's
    start (a later pool with the same environment reuses that server), and a NumPy
    global seed of its own."""
    monkeypatch.setenv("ELASTIC_GYM_TEST_MARK", "first")
    here = os.getcwd()
    with worker_processes(2) as pool:
        first = [seen for _, _, seen in pool.results(what_a_job_sees, [0, 1])]
    saved = os.dup(1)
    try:
        with (tmp_path / "out.txt").open("w") as out:
            os.dup2(out.fileno(), 1)
        with worker_processes(1) as pool:
            [(_, _, again)] = pool.results(what_a_job_sees, [2])
    finally:
        os.dup2(saved, 1)
        os.close(saved)
    monkeypatch.setenv("ELASTIC_GYM_TEST_MARK", "second")
    monkeypatch.chdir(tmp_path)
    with worker_processes(1) as pool:
        [(_, _, second)] = pool.results(what_a_job_sees, [3])
    assert [seen["mark"] for seen in [*first, again, second]] == ["first"] * 3 + ["second"]
    assert {seen["cwd"] for seen in [*first, again]} == {here} and second["cwd"] == str(tmp_path)
    for seen in [*first, again, second]:  # single-threaded BLAS (`single_threaded`)
        assert seen["blas"] == "1" and seen["blas threads"] == {1}
    if fork_server.available():  # one server for both pools of the first environment
        assert {seen["parent"] for seen in [*first, again]} == {first[0]["parent"]}
        assert first[0]["parent"] != os.getpid()
        # which readied numba's compiler once for every worker (`numba_ready`)
        assert all(seen["numba ready"] for seen in [*first, again, second])
    assert len({seen["pid"] for seen in first}) == 2
    assert len({seen["draw"] for seen in [*first, again, second]}) == 4
    assert (tmp_path / "out.txt").read_text() == f"job 2 in {again['pid']}\n"


@pytest.mark.slow
@pytest.mark.skipif(not fork_server.available(), reason="workers are spawned here")
def test_a_server_that_preloaded_more_serves_a_pool_that_asks_for_less():
    """The pre-run check's own processes (after a death) fork from the runs' server, which
    preloaded the check's module too: no second server imports the package again."""
    with worker_processes(1, preload=["elastic_gym.evaluation.preflight"]) as runs:
        [(_, _, run)] = runs.results(what_a_job_sees, [0])
        with worker_processes(1) as check:
            [(_, _, checked)] = check.results(what_a_job_sees, [1])
    assert checked["parent"] == run["parent"] and checked["pid"] != run["pid"]


def test_numba_ready_refreshes_numbas_contexts_as_a_first_compile_would(monkeypatch):
    """What a fork server imports last (`fork_server.READY`) installs numba's registries
    (the refresh of its CPU target's contexts); that a forked worker has them: the pool
    test above."""
    from numba.core.registry import cpu_target

    ready = importlib.import_module(fork_server.READY)
    refreshed = []
    context = cpu_target.target_context
    monkeypatch.setattr(type(context), "refresh", lambda self: refreshed.append(self))
    importlib.reload(ready)  # its code run again
    assert refreshed == [context]


@pytest.mark.slow
def test_where_there_is_no_fork_server_workers_are_spawned_children(monkeypatch):
    """Not Linux, Python < 3.11: the worker is this process's own spawned child (the same
    worker loop, given this process's pid as its parent) and sees the environment."""
    monkeypatch.setattr(fork_server, "available", lambda: False)
    monkeypatch.setenv("ELASTIC_GYM_TEST_MARK", "spawned")
    with worker_processes(1) as pool:
        [(_, ok, seen)] = pool.results(what_a_job_sees, [0])
    assert ok and seen["parent"] == os.getpid() and seen["mark"] == "spawned"


def test_the_fork_server_follows_only_the_launch_it_was_written_for(monkeypatch):
    """`_Popen._launch` follows multiprocessing's own: this Python's is that one (the
    fork server is used here), and any other makes workers spawn."""
    from multiprocessing import popen_forkserver

    assert fork_server._launch_followed()

    def launch(self, process_obj):  # the same but for one more step
        process_obj.checked = True

    monkeypatch.setattr(popen_forkserver.Popen, "_launch", launch)
    assert not fork_server._launch_followed()
    monkeypatch.delattr(popen_forkserver.Popen, "_launch")
    assert not fork_server._launch_followed()


@pytest.mark.slow
def test_workers_and_their_fork_server_ignore_sigint():
    """A Ctrl-C reaches the whole process group: only the owner decides what stops."""
    with worker_processes(1) as pool:
        [(_, _, seen)] = pool.results(what_a_job_sees, [0])
        if seen["parent"] != os.getpid():  # the fork server
            os.kill(seen["parent"], signal.SIGINT)
        os.kill(seen["pid"], signal.SIGINT)
        time.sleep(0.5)
        [(_, ok, again)] = pool.results(what_a_job_sees, [1])
    assert ok and (again["pid"], again["parent"]) == (seen["pid"], seen["parent"])


BUSY_OWNER = """
import time
from elastic_gym.runtime.parallel import worker_processes
with worker_processes(2) as pool:
    for _ in pool.results(time.sleep, [600.0, 600.0]):
        pass
"""
ENDING_BOUND = 60.0  # s for busy workers to end once their owner is killed (their jobs: 600 s)


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_busy_workers_and_their_server_end_when_the_owner_is_killed(tmp_path):
    """``kill -9`` of the owner while its workers run jobs of 10 minutes: the fork server
    sees its alive pipe close and exits, and the kernel kills the workers
    (PR_SET_PDEATHSIG against the server); nothing the owner started is left."""
    # its temporary folder here: multiprocessing's pymp-* folder, which a killed process leaves
    owner = subprocess.Popen(
        [sys.executable, "-c", BUSY_OWNER], env=checkout_env(TMPDIR=str(tmp_path))
    )
    deadline = time.monotonic() + 120.0
    while len(workers_of(owner.pid)) < 2:
        assert owner.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    time.sleep(0.5)  # the jobs have started
    started = descendants(owner.pid)
    owner.kill()
    owner.wait()
    deadline = time.monotonic() + ENDING_BOUND
    while any(alive(pid) for pid in started) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = [pid for pid in started if alive(pid)]
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    assert not left


@pytest.mark.slow
def test_a_call_left_early_does_not_leak_its_results_into_the_next():
    with worker_processes(2) as pool:
        results = pool.results(slow_square, [4, 4, 4, 4])
        next(results)
        with pytest.raises(RuntimeError, match="one results\\(\\) call at a time"):
            next(pool.results(slow_square, [1]))
        results.close()  # the other worker is still busy with a job of this call
        assert sorted(value for _, _, value in pool.results(slow_square, [1, 2, 3])) == [1, 4, 9]


@pytest.mark.slow
def test_a_worker_that_died_between_two_calls_is_replaced():
    with worker_processes(1) as pool:
        [(_, _, (_, pid))] = pool.results(pid_of, [0])
        os.kill(pid, signal.SIGKILL)
        for _ in range(100):  # until the kernel has ended it
            if not pool._workers[0].process.is_alive():
                break
            time.sleep(0.05)
        [(_, ok, (_, other))] = pool.results(pid_of, [1])
    assert ok and other != pid


@pytest.mark.slow
def test_the_pre_run_check_runs_in_a_worker_of_the_runs(tmp_path: Path):
    """One worker: the check and every run are built in the same process, not this one
    (a spawned process costs seconds of imports)."""
    log = tmp_path / "pids.txt"
    scenario = Scenario.from_dict(
        {
            "name": "pids",
            "duration": 0.01,
            "seeds": [0, 1],
            "envs": [{"id": "TwoLinkElastic-v0"}],
            "controllers": [{"name": "pid-log", "class": PidLog, "options": {"log": str(log)}}],
            "state_sources": ["true"],
        }
    )
    compare(
        scenario,
        output_dir=tmp_path / "out",
        workers=1,
        batch_size=1,
        progress=False,
        plots=False,
        console=Console(quiet=True),
    )
    pids = log.read_text().split()
    assert len(pids) >= 3  # the check's build and the two runs'
    assert len(set(pids)) == 1 and pids[0] != str(os.getpid())
