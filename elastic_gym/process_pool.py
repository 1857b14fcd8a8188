"""A pool of spawned worker processes that die with their parent and survive a dead worker.

:class:`WorkerPool` runs one job at a time per worker, so it always knows which job a
worker was running: a worker that dies (``os._exit``, a segmentation fault, the OOM
killer) fails exactly that job (:class:`WorkerDiedError`), and a fresh worker takes its
place; the other jobs go on.

Workers end when their parent does, however it ends (``kill -9`` included): on Linux
the kernel sends them ``SIGKILL`` (``prctl(PR_SET_PDEATHSIG)``), and every worker also
checks its parent's pid each :data:`PARENT_CHECK` seconds while it waits for a job.
Workers ignore SIGINT (a Ctrl-C in a terminal reaches the whole process group; the
parent alone decides what to stop).
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import pickle
import signal
import sys
from collections.abc import Callable, Iterator
from multiprocessing.connection import Connection, wait
from typing import Any

PARENT_CHECK = 1.0  # s between checks of the parent's pid in an idle worker
STOP_TIMEOUT = 5.0  # s a terminated worker gets before it is killed
PR_SET_PDEATHSIG = 1


class WorkerDiedError(RuntimeError):
    """The worker process running a job died; ``exitcode`` as in ``multiprocessing``
    (negative: killed by that signal)."""

    def __init__(self, exitcode: int | None, detail: str | None = None) -> None:
        self.exitcode = exitcode
        super().__init__(f"its worker process died ({detail or exit_description(exitcode)})")


def exit_description(exitcode: int | None) -> str:
    """``"killed by SIGSEGV"``, ``"exit code 3"`` or ``"no exit code"``."""
    if exitcode is None:
        return "no exit code"
    if exitcode < 0:
        try:
            return f"killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"killed by signal {-exitcode}"
    return f"exit code {exitcode}"


def die_with_parent(parent_pid: int) -> None:
    """Ask the kernel to SIGKILL this process when its parent ends (Linux), and end now
    if the parent has already gone."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent_pid:
        os._exit(1)


def _picklable_error(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a ``RuntimeError`` with its text."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc


def _worker(connection: Connection, function: Callable[[Any], Any], parent_pid: int) -> None:
    """Worker loop: receive ``job``, send ``(True, result)`` or ``(False, exception)``;
    ``None`` (or a closed pipe, or a dead parent) ends it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(parent_pid)
    while True:
        while not connection.poll(PARENT_CHECK):
            if os.getppid() != parent_pid:
                os._exit(1)
        try:
            job = connection.recv()
        except (EOFError, OSError):
            return
        if job is None:
            return
        try:
            reply: tuple[bool, Any] = (True, function(job))
        except BaseException as exc:  # sent to the parent, which decides
            reply = (False, _picklable_error(exc))
        try:
            connection.send(reply)
        except Exception as exc:  # an unpicklable result
            connection.send((False, RuntimeError(f"cannot send the result back: {exc}")))


class _Worker:
    def __init__(self, context, function: Callable[[Any], Any], spawn_env: Callable) -> None:
        self.connection, child = context.Pipe()
        self.process = context.Process(
            target=_worker, args=(child, function, os.getpid()), daemon=True
        )
        with spawn_env():
            self.process.start()
        child.close()
        self.job: int | None = None  # index of the job it runs


class WorkerPool:
    """``workers`` spawned processes computing ``function(job)``.

    ``spawn_env``: a context manager entered while a worker starts (e.g. the
    environment variables it inherits). Use as a context manager: leaving it ends every
    worker (terminate, then kill), whatever happened.
    """

    def __init__(
        self,
        function: Callable[[Any], Any],
        workers: int,
        spawn_env: Callable[[], contextlib.AbstractContextManager] = contextlib.nullcontext,
    ) -> None:
        self._context = multiprocessing.get_context("spawn")
        self._function, self._spawn_env = function, spawn_env
        self._size = workers
        self._workers: list[_Worker] = []

    def __enter__(self) -> WorkerPool:
        return self

    def __exit__(self, *exc_info) -> None:
        self.stop()

    def results(self, jobs: list[Any]) -> Iterator[tuple[int, bool, Any]]:
        """Yield ``(index, True, result)``, ``(index, False, exception)`` for every job in
        completion order; a job whose worker died gives :class:`WorkerDiedError`."""
        queue = iter(enumerate(jobs))
        size = min(self._size, len(jobs))
        while len(self._workers) < size:
            self._workers.append(_Worker(self._context, self._function, self._spawn_env))
        busy = 0
        for worker in self._workers:
            busy += self._give(worker, queue)
        while busy:
            waiting = [w for w in self._workers if w.job is not None]
            ready = wait([w.connection for w in waiting] + [w.process.sentinel for w in waiting])
            for worker in waiting:
                if worker.connection not in ready and worker.process.sentinel not in ready:
                    continue
                index, outcome = worker.job, self._collect(worker)
                worker.job = None
                busy -= 1
                if outcome is None:  # the worker died: replace it
                    self._workers.remove(worker)
                    worker.process.join()
                    died = WorkerDiedError(worker.process.exitcode)
                    worker = _Worker(self._context, self._function, self._spawn_env)
                    self._workers.append(worker)
                    outcome = (False, died)
                busy += self._give(worker, queue)
                yield (index, *outcome)

    @staticmethod
    def _give(worker: _Worker, queue: Iterator) -> int:
        item = next(queue, None)
        if item is None:
            return 0
        worker.job = item[0]
        worker.connection.send(item[1])
        return 1

    @staticmethod
    def _collect(worker: _Worker) -> tuple[bool, Any] | None:
        """The worker's reply, or ``None`` if it died without one."""
        try:
            if worker.connection.poll():
                return worker.connection.recv()
        except (EOFError, OSError):
            pass
        return None

    def stop(self) -> None:
        """End every worker now: ask idle ones to leave, terminate, then kill."""
        workers, self._workers = self._workers, []
        for worker in workers:
            with contextlib.suppress(OSError):
                worker.connection.close()
            if worker.process.is_alive():
                worker.process.terminate()
        for worker in workers:
            worker.process.join(STOP_TIMEOUT)
            if worker.process.is_alive():
                worker.process.kill()
                worker.process.join()
