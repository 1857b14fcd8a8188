"""A pool of worker processes that die with their parent and survive a dead worker.

`WorkerPool` runs one job at a time per worker, so it always knows which job a
worker was running: a worker that dies (``os._exit``, a segmentation fault, the OOM
killer) fails exactly that job (`WorkerDiedError`), and a fresh worker takes its
place; the other jobs go on. Workers are forked from a server that has imported the
modules of the pool's jobs (`fork_server`; spawned where there is none).

Workers end when their owner does, however it ends (``kill -9`` included): the
server exits when its owner does, and on Linux the kernel then sends the workers
``SIGKILL`` (``prctl(PR_SET_PDEATHSIG)``); an idle worker also checks its parent's pid
each `PARENT_CHECK` seconds. Workers ignore SIGINT (a Ctrl-C in a terminal reaches the
whole process group; the owner alone decides what to stop). A worker imports the
owner's ``__main__`` module (a script runs again up to its ``__main__`` guard) only when
the function or the jobs refer to it (`refers_to_main`).
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import io
import multiprocessing
import os
import pickle
import signal
import sys
import types
from collections.abc import Callable, Iterator, Sequence
from multiprocessing.connection import Connection, wait
from typing import Any

from elastic_gym.runtime.fork_server import owned, start_process

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


class _MainFinder(pickle.Pickler):
    """A pickler that notes whether what it pickles refers to a class or function of
    ``__main__``."""

    def __init__(self) -> None:
        super().__init__(io.BytesIO(), protocol=pickle.HIGHEST_PROTOCOL)
        self.found = False

    def reducer_override(self, obj: Any) -> Any:
        if isinstance(obj, (type, types.FunctionType)) and obj.__module__ == "__main__":
            self.found = True
        return NotImplemented


def refers_to_main(*objects: Any) -> bool:
    """Whether ``objects`` can only be rebuilt in another process with this process's
    ``__main__`` module: they refer to a class or function defined there (a script, a
    notebook), or they do not pickle at all."""
    finder = _MainFinder()
    try:
        finder.dump(objects)
    except Exception:
        return True
    return finder.found


@contextlib.contextmanager
def main_not_imported() -> Iterator[None]:
    """While a worker starts: a bare ``__main__`` module, so that the new process does
    not import the parent's main script (``multiprocessing`` imports it when it has a
    file or a module spec)."""
    main = sys.modules["__main__"]
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        sys.modules["__main__"] = main


def _picklable_error(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a ``RuntimeError`` with its text."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc


def _worker(parent_pid: int, connection: Connection) -> None:
    """Worker loop: receive ``(function, job)``, send ``(True, function(job))`` or
    ``(False, exception)``; ``None`` (or a closed pipe, or a dead parent) ends it.
    ``parent_pid``: its parent process (the fork server, or the owner)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(parent_pid)
    while True:
        while not connection.poll(PARENT_CHECK):
            if os.getppid() != parent_pid:
                os._exit(1)
        try:
            message = connection.recv()
        except (EOFError, OSError):
            return
        if message is None:
            return
        try:
            function, job = message
            reply: tuple[bool, Any] = (True, function(job))
        except BaseException as exc:  # sent to the parent, which decides
            reply = (False, _picklable_error(exc))
        try:
            connection.send(reply)
        except Exception as exc:  # an unpicklable result
            connection.send((False, RuntimeError(f"cannot send the result back: {exc}")))


def _module_of(function: Callable) -> str | None:
    """The module defining ``function`` (through ``functools.partial``)."""
    while isinstance(function, functools.partial):
        function = function.func
    return getattr(function, "__module__", None)


class _Worker:
    def __init__(self, spawn_env: Callable, main: bool, preload: tuple[str, ...]) -> None:
        self.connection, child = multiprocessing.Pipe()
        with spawn_env(), contextlib.nullcontext() if main else main_not_imported():
            self.process = start_process(_worker, (child,), preload)
        child.close()
        self.job: int | None = None  # index of the job it runs


class _Queue:
    """The jobs not yet given to a worker, with their indices."""

    def __init__(self, jobs: list[Any]) -> None:
        self._jobs, self._next = jobs, 0

    def waiting(self) -> bool:
        return self._next < len(self._jobs)

    def next(self) -> tuple[int, Any]:
        index = self._next
        self._next += 1
        return index, self._jobs[index]


class WorkerPool:
    """Up to ``workers`` processes computing ``function(job)`` for the jobs of each
    `results` call; the workers of one call stay for the next (one pool can serve
    several functions: their imports are paid once).

    ``spawn_env``: a context manager entered while a worker starts (e.g. the
    environment variables it inherits). ``preload``: modules the jobs import, imported
    once by the fork server (besides the module of the first function, if it is this
    package's). Use as a context manager: leaving it ends every worker (terminate, then
    kill), whatever happened.
    """

    def __init__(
        self,
        workers: int,
        spawn_env: Callable[[], contextlib.AbstractContextManager] = contextlib.nullcontext,
        preload: Sequence[str] = (),
    ) -> None:
        self._preload = tuple(preload)
        self._modules = self._preload  # what the workers' server preloads (set by _spawn)
        self._spawn_env = spawn_env
        self._size = workers
        self._workers: list[_Worker] = []
        self._running = False  # a results() call is under way
        self._main = False  # whether the workers import __main__ (set by results)

    def __enter__(self) -> WorkerPool:
        return self

    def __exit__(self, *exc_info) -> None:
        self.stop()

    def start(self, function: Callable[[Any], Any], jobs: list[Any]) -> None:
        """Start the workers now, for ``function`` and ``jobs`` to come (whether they
        need ``__main__``), so that their start overlaps what this process does next."""
        self._spawn(function, refers_to_main(function, jobs), self._size)

    def results(
        self, function: Callable[[Any], Any], jobs: list[Any], workers: int | None = None
    ) -> Iterator[tuple[int, bool, Any]]:
        """Yield ``(index, True, function(job))``, ``(index, False, exception)`` for every
        job in completion order, on at most ``workers`` of the pool's workers (default:
        all); a job whose worker died gives `WorkerDiedError`. One call at a time;
        a call left early (an exception, a generator closed) ends the workers still
        running its jobs, so the next call never receives their results."""
        if self._running:
            raise RuntimeError("a WorkerPool runs the jobs of one results() call at a time")
        queue = _Queue([(function, job) for job in jobs])
        size = min(self._size if workers is None else workers, len(jobs))
        self._spawn(function, refers_to_main(function, jobs), size)
        self._running = True
        try:
            busy = sum(self._give(worker, queue) for worker in self._workers[:size])
            while busy:
                waiting = [w for w in self._workers if w.job is not None]
                ready = wait(
                    [w.connection for w in waiting] + [w.process.sentinel for w in waiting]
                )
                for worker in waiting:
                    if worker.connection not in ready and worker.process.sentinel not in ready:
                        continue
                    index, outcome = worker.job, self._collect(worker)
                    worker.job = None
                    busy -= 1
                    if outcome is None:  # the worker died: replaced if a job waits
                        self._workers.remove(worker)
                        worker.process.join()
                        outcome = (False, WorkerDiedError(worker.process.exitcode))
                        if queue.waiting():
                            worker = self._new_worker()
                            self._workers.append(worker)
                    if worker in self._workers:
                        busy += self._give(worker, queue)
                    yield (index, *outcome)
        finally:
            self._running = False
            if any(worker.job is not None for worker in self._workers):
                self.stop()

    def _spawn(self, function: Callable, main: bool, size: int) -> None:
        """At least ``size`` live workers, importing ``__main__`` if ``main`` (a worker
        that died while idle, between two calls, is replaced); new workers of an empty
        pool preload the module of ``function`` if it is this package's."""
        for worker in [w for w in self._workers if not w.process.is_alive()]:
            self._workers.remove(worker)
            worker.process.join()
        if main and not self._main:
            self.stop()  # workers started without __main__ cannot rebuild these jobs
        if not self._workers:
            self._main = main
            module = _module_of(function)
            self._modules = self._preload + ((module,) if module and owned(module) else ())
        while len(self._workers) < size:
            self._workers.append(self._new_worker())

    def _new_worker(self) -> _Worker:
        return _Worker(self._spawn_env, self._main, self._modules)

    @staticmethod
    def _give(worker: _Worker, queue: _Queue) -> int:
        if not queue.waiting():
            return 0
        worker.job, job = queue.next()
        worker.connection.send(job)
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
