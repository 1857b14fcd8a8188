"""The orphan reaper's choice of processes and its end of them, in this process (the
watcher itself runs only when a parent dies: tests/test_reliability.py kills one)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from elastic_gym.runtime import orphan_reaper

pytestmark = pytest.mark.skipif(not orphan_reaper.PROC.is_dir(), reason="Linux /proc only")

SLEEP = "import time; time.sleep(60)"


def test_it_notes_ray_descendants_only_and_kills_exactly_those():
    """A child whose command line is Ray's (``/ray/`` in it) is noted with its start time,
    a plain child is not; ending the noted ones kills the Ray child (SIGKILL) and leaves
    the other running."""
    ray_like = subprocess.Popen([sys.executable, "-c", SLEEP, "/ray/raylet"])
    plain = subprocess.Popen([sys.executable, "-c", SLEEP, "plain"])
    try:
        noted = orphan_reaper.ray_descendants(os.getpid())
        assert ray_like.pid in noted and plain.pid not in noted
        own = {pid: start for pid, start in noted.items() if pid == ray_like.pid}
        assert orphan_reaper._alive(own) == [ray_like.pid]
        orphan_reaper._end(own)
        assert ray_like.wait(timeout=10) == -9
        assert orphan_reaper._alive(own) == []
        assert plain.poll() is None
    finally:
        for child in (ray_like, plain):
            child.kill()
            child.wait()


def test_a_reused_pid_is_not_the_noted_process():
    """A noted pid whose start time differs is another process now: not alive, not
    killed."""
    plain = subprocess.Popen([sys.executable, "-c", SLEEP])
    try:
        parent, start = orphan_reaper._stat(plain.pid)
        assert parent == os.getpid()
        assert orphan_reaper._alive({plain.pid: start + 1}) == []
        orphan_reaper._end({plain.pid: start + 1})
        assert plain.poll() is None
    finally:
        plain.kill()
        plain.wait()


def test_a_worker_its_raylet_started_before_both_were_orphaned_is_ended_too():
    """A Ray process that names a noted raylet in ``RAY_RAYLET_PID`` is ended with it
    although it is not the raylet's child (the kernel ends a raylet with its parent; a
    worker it had just started goes to another parent before the watcher looks). One
    naming another raylet, or not Ray's, stays."""
    raylet = subprocess.Popen([sys.executable, "-c", SLEEP, "/ray/raylet"])
    env = {**os.environ, "RAY_RAYLET_PID": str(raylet.pid)}
    worker = subprocess.Popen([sys.executable, "-c", SLEEP, "/ray/default_worker.py"], env=env)
    plain = subprocess.Popen([sys.executable, "-c", SLEEP, "plain"], env=env)
    other_env = {**os.environ, "RAY_RAYLET_PID": str(plain.pid)}
    other = subprocess.Popen([sys.executable, "-c", SLEEP, "/ray/default_worker.py"], env=other_env)
    try:
        noted = {raylet.pid: orphan_reaper._stat(raylet.pid)[1]}
        assert worker.pid not in orphan_reaper.ray_descendants(raylet.pid)
        assert set(orphan_reaper.orphans(noted)) == {worker.pid}
        orphan_reaper._end(noted)
        assert raylet.wait(timeout=10) == -9 and worker.wait(timeout=10) == -9
        assert plain.poll() is None and other.poll() is None
    finally:
        for child in (raylet, worker, plain, other):
            child.kill()
            child.wait()
