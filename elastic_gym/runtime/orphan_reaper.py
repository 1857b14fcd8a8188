"""End the Ray processes a parent started when the parent dies without shutting Ray down.

A local Ray runtime started by ``ray.init`` (GCS, raylet, its agents and workers)
outlives a parent killed with ``kill -9``. `start_reaper` starts a small
watcher process (this file run as a script with the parent's pid, in its own
session) that every `SNAPSHOT_PERIOD` seconds notes the parent's descendants
whose command line is Ray's (``/ray/`` in it, or a ``ray::`` worker). When its stdin
(a pipe only the parent holds) closes, the parent has ended; if the parent is really
gone, the noted processes still alive (same pid and start time) are stopped with
SIGSTOP together with every Ray process they started meanwhile (a raylet's workers
handed to another parent name it in ``RAY_RAYLET_PID``), then killed with SIGKILL (an
orphaned runtime has no one to shut down for). Linux only (it reads ``/proc``);
elsewhere `start_reaper` does nothing.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

SNAPSHOT_PERIOD = 0.5  # s between looks at the parent's descendants
EXIT_WAIT = 5.0  # s for the parent to finish dying once its end of the pipe is closed
FREEZE_ROUNDS = 20  # looks for processes started while the others are being frozen
PROC = Path("/proc")


def _stat(pid: int) -> tuple[int, int] | None:
    """(parent pid, start time) of a process, ``None`` if it is gone."""
    try:
        text = (PROC / str(pid) / "stat").read_text()
        fields = text[text.rindex(")") + 2 :].split()  # after "pid (comm) "
        return int(fields[1]), int(fields[19])
    except (OSError, ValueError, IndexError):  # gone, or caught while it exits
        return None


def _is_ray(pid: int) -> bool:
    try:
        command = (PROC / str(pid) / "cmdline").read_bytes().replace(b"\0", b" ")
    except OSError:
        return False
    return b"/ray/" in command or command.startswith(b"ray::")


def _process_table() -> tuple[dict[int, list[int]], dict[int, int]]:
    """(parent pid -> child pids, pid -> start time) of every process."""
    children: dict[int, list[int]] = {}
    starts: dict[int, int] = {}
    for entry in PROC.iterdir():
        if entry.name.isdigit() and (stat := _stat(int(entry.name))) is not None:
            children.setdefault(stat[0], []).append(int(entry.name))
            starts[int(entry.name)] = stat[1]
    return children, starts


def ray_descendants(*roots: int) -> dict[int, int]:
    """pid -> start time of the Ray processes among the descendants of ``roots``."""
    children, starts = _process_table()
    found: dict[int, int] = {}
    stack = [child for root in roots for child in children.get(root, ())]
    while stack:
        pid = stack.pop()
        if pid != os.getpid() and _is_ray(pid):
            found[pid] = starts[pid]
        stack += children.get(pid, ())
    return found


def _raylet_of(pid: int) -> int | None:
    """The raylet a Ray worker or agent was started by (``RAY_RAYLET_PID`` in its
    environment), ``None`` if it names none."""
    try:
        environ = (PROC / str(pid) / "environ").read_bytes().split(b"\0")
    except OSError:
        return None
    for entry in environ:
        if entry.startswith(b"RAY_RAYLET_PID="):
            with contextlib.suppress(ValueError):
                return int(entry.removeprefix(b"RAY_RAYLET_PID="))
    return None


def orphans(noted: dict[int, int]) -> dict[int, int]:
    """pid -> start time of the Ray processes not in ``noted`` whose raylet is: a worker
    that a raylet started just before both lost their parent (the kernel ends a raylet
    with its parent; the worker, handed to another parent, is no longer its child)."""
    _, starts = _process_table()
    return {
        pid: start
        for pid, start in starts.items()
        if pid not in noted
        and pid != os.getpid()
        and (raylet := _raylet_of(pid)) in noted
        and start >= noted[raylet]  # not an older process with a reused raylet pid
        and _is_ray(pid)
    }


def _alive(noted: dict[int, int]) -> list[int]:
    """The noted processes still running (same pid and start time)."""
    return [pid for pid, start in noted.items() if (stat := _stat(pid)) and stat[1] == start]


def _end(noted: dict[int, int]) -> None:
    """Freeze the noted processes and every Ray process they start meanwhile (a raylet
    respawns its workers) or started just before (`orphans`), then kill them all."""
    for _ in range(FREEZE_ROUNDS):
        for pid in _alive(noted):
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGSTOP)
        found = {**ray_descendants(*_alive(noted)), **orphans(noted)}
        more = {p: t for p, t in found.items() if p not in noted}
        if not more:
            break
        noted.update(more)
    for pid in _alive(noted):
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)


def watch(parent: int) -> None:
    """The watcher's loop (see the module docstring)."""
    noted: dict[int, int] = {}
    while True:
        readable, _, _ = select.select([sys.stdin.fileno()], [], [], SNAPSHOT_PERIOD)
        if readable and not os.read(sys.stdin.fileno(), 4096):
            break
        noted.update(ray_descendants(parent))
        noted = {pid: start for pid, start in noted.items() if _stat(pid) is not None}
    deadline = time.monotonic() + EXIT_WAIT  # a dying parent closes its files before its
    while os.getppid() == parent:  # children are handed to another parent
        if time.monotonic() > deadline:
            return  # the parent lives on: it closed the pipe itself
        time.sleep(0.01)
    _end(noted)


_reaper: subprocess.Popen | None = None


def start_reaper() -> None:
    """Start this process's watcher once (Linux; a no-op elsewhere or if running)."""
    global _reaper
    if not PROC.is_dir() or (_reaper is not None and _reaper.poll() is None):
        return
    _reaper = subprocess.Popen(
        [sys.executable, __file__, str(os.getpid())],  # standard library only
        stdin=subprocess.PIPE,
        start_new_session=True,
    )


if __name__ == "__main__":
    watch(int(sys.argv[1]))
