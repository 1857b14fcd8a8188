"""Run independent jobs in parallel: local worker processes or a Ray cluster, one code path.

Used by the comparison (one job = one episode) and multi-seed training (one job = one
run). `for_each_result` hands every result to the caller as soon as it arrives;
`run_jobs` collects them in order. Workers run single-threaded BLAS and torch
(`single_threaded`: competing threads slow small matrices by orders of magnitude).
While jobs run, SIGINT and SIGTERM raise `Interrupted` (a ``KeyboardInterrupt``)
in the main thread: queued jobs are cancelled, the workers terminated (Ray shut down if
this call started it), and the results delivered before stay with the caller. Workers
ignore SIGINT: the parent alone decides what to stop.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from rich.progress import Progress
from threadpoolctl import threadpool_limits

from elastic_gym.runtime.orphan_reaper import start_reaper
from elastic_gym.runtime.process_pool import WorkerDiedError, WorkerPool, refers_to_main
from elastic_gym.validation import checked_count, lookup

BACKENDS = ("process", "ray")
DEFAULT_BACKEND = BACKENDS[0]  # local worker processes
SINGLE_THREAD_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
RAY_POLL = 0.5  # s between checks for signals while waiting on Ray
RAY_IN_FLIGHT = 4  # Ray tasks submitted per worker; the rest wait here (cancelled for free)


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM arrived while jobs ran; ``exit_code`` is 128 + the signal number.

    ``detail`` says what was kept (set by the caller that cleaned up).
    """

    def __init__(self, signum: int, detail: str = "") -> None:
        self.signum = signum
        self.signal_name = signal.Signals(signum).name
        self.detail = detail
        super().__init__(f"interrupted by {self.signal_name}" + (f": {detail}" if detail else ""))

    @classmethod
    def of(cls, exc: KeyboardInterrupt, detail: str) -> Interrupted:
        """``exc`` with the detail of what was kept. A plain ``KeyboardInterrupt`` is the
        last signal received inside `interrupts_raised` (Ray turns the exception
        our handler raises inside its waits into one), else SIGINT."""
        return cls(getattr(exc, "signum", _received or signal.SIGINT), detail)

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


def user_failure(exc: BaseException) -> bool:
    """Whether ``exc``, raised by a job's own code, is that job's failure rather than a
    reason to stop everything: any ``Exception``, ``SystemExit`` (``sys.exit()`` in a
    user's code) and a ``KeyboardInterrupt`` raised by the code itself; not the
    `Interrupted` of a real SIGINT/SIGTERM."""
    return isinstance(exc, (Exception, SystemExit)) or (
        isinstance(exc, KeyboardInterrupt) and not isinstance(exc, Interrupted)
    )


def with_detail(exc: BaseException, detail: str) -> BaseException:
    """What to raise once a caller has cleaned up after ``exc`` and can say what it kept:
    an `Interrupted` (from any ``KeyboardInterrupt``) or a ``RuntimeError``
    ``"<exc>; <detail>"`` (from an ``Exception``, chained), else ``exc`` itself."""
    if isinstance(exc, KeyboardInterrupt):
        replacement: BaseException = Interrupted.of(exc, detail)
    elif isinstance(exc, Exception):
        replacement = RuntimeError(f"{exc}; {detail}")
        replacement.__cause__ = exc
    else:
        return exc
    replacement.__suppress_context__ = True
    return replacement


_handlers_depth = 0
_received: int | None = None  # the signal being handled, while interrupts_raised is active


def _raise_interrupted(signum: int, frame: object) -> None:
    global _received
    if _received is not None:  # the cleanup of the first signal is not interrupted
        return
    _received = signum
    raise Interrupted(signum)


@contextmanager
def interrupts_raised() -> Iterator[None]:
    """Inside this block SIGINT and SIGTERM raise `Interrupted` in the main thread.

    Only the first signal raises (later ones are ignored until the outermost block ends,
    so cleanup runs to its end). Outside the main thread this does nothing. The previous
    handlers are restored at the end.
    """
    global _handlers_depth, _received
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {}
    if _handlers_depth == 0:
        _received = None
        previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
        _install_handlers()
    _handlers_depth += 1
    try:
        yield
    finally:
        _handlers_depth -= 1
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _install_handlers() -> None:
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _raise_interrupted)


def default_workers(n_jobs: int) -> int:
    return max(1, min(n_jobs, os.cpu_count() or 1))


def resolve_workers(workers: int | None, n_jobs: int, backend: str) -> int:
    """The number of workers for ``n_jobs`` jobs (default: one per CPU); checks the
    arguments (``ValueError``)."""
    lookup(dict.fromkeys(BACKENDS), backend, "backend")
    return default_workers(n_jobs) if workers is None else checked_count(workers, "workers", 1)


def for_each_result(
    function: Callable[[Any], Any],
    jobs: Sequence[Any],
    on_result: Callable[[int, Any], None],
    workers: int | None = None,
    backend: str = DEFAULT_BACKEND,
    progress: bool = True,
    label: str = "jobs",
    describe: Callable[[Any], str] = repr,
    crashed: Callable[[Any, WorkerDiedError], Any] | None = None,
    size: Callable[[Any], int] | None = None,
    pool: WorkerPool | None = None,
    preload: Sequence[str] = (),
) -> None:
    """Compute ``function(job)`` for every job in parallel and call ``on_result(index,
    result)`` in this process as each one completes (in completion order).

    ``size(job)``: how many items of the progress bar a job counts for (default 1: a
    batch of runs counts as its runs). ``pool``: the worker processes of
    `worker_processes` to run on (``backend="process"``; at most ``workers`` of
    them), kept for the caller's next call; default: new ones, ended on return, that
    fork from a server which imported ``preload`` (modules the jobs import: this package's
    or installed libraries, never user code) and the module of ``function`` (if it is
    this package's), so that each worker does not import them again.

    A worker process that dies while running a job (``os._exit``, a segmentation
    fault): with ``crashed``, ``crashed(job, WorkerDiedError)`` is that job's result and the
    other jobs go on (a fresh worker replaces the dead one); without it, a
    ``RuntimeError`` naming that job. Workers end when this process ends, however it
    ends (`process_pool`; Ray: `orphan_reaper`).

    ``backend="process"``: worker processes, one with ``workers=1``; only jobs
    that refer to ``__main__`` (a class defined in a notebook or in the script; see
    `refers_to_main`) run in this process with one worker,
    where code that ends its process ends this one.
    ``backend="ray"``: a local Ray runtime with ``workers`` CPUs is started unless
    ``ray.init`` was already called, or the environment variable ``RAY_ADDRESS`` names a
    running cluster (``ray start --head`` on one machine, ``ray start --address=HEAD:6379``
    on the others, then ``RAY_ADDRESS=HEAD:6379``): then that cluster is used, with as
    many jobs in flight as it has CPUs. A job that
    raises cancels the others and raises ``RuntimeError`` naming it (``describe``);
    SIGINT/SIGTERM raise `Interrupted` after stopping every worker (see the
    module docstring). ``function`` and the jobs must be picklable (module-level
    function, plain data).
    """
    workers = resolve_workers(workers, len(jobs), backend)
    with interrupts_raised(), Progress(disable=not progress, transient=False) as bar:
        weight = size or (lambda job: 1)
        task = bar.add_task(label, total=sum(weight(job) for job in jobs))

        def settle(index: int, ok: bool, outcome: Any) -> None:
            """A job's result (``ok``) or exception: results go to ``on_result``, as does
            ``crashed(job, WorkerDiedError)`` when given; other exceptions are raised as a
            ``RuntimeError`` naming the job."""
            if not ok and crashed is not None and isinstance(outcome, WorkerDiedError):
                ok, outcome = True, crashed(jobs[index], outcome)
            if not ok:
                raise RuntimeError(
                    f"{describe(jobs[index])} could not run: {type(outcome).__name__}: {outcome}"
                ) from outcome
            on_result(index, outcome)
            bar.advance(task, weight(jobs[index]))

        if backend == "ray":
            _run_ray(function, jobs, workers, settle)
        elif workers == 1 and refers_to_main(function, jobs):
            with single_threaded():
                for index, job in enumerate(jobs):
                    try:
                        ok, outcome = True, function(job)
                    except Exception as exc:
                        ok, outcome = False, exc
                    settle(index, ok, outcome)
        else:
            _run_processes(function, jobs, workers, settle, pool, preload)


def run_jobs(
    function: Callable[[Any], Any],
    jobs: Sequence[Any],
    workers: int | None = None,
    backend: str = DEFAULT_BACKEND,
    progress: bool = True,
    label: str = "jobs",
    describe: Callable[[Any], str] = repr,
    crashed: Callable[[Any, WorkerDiedError], Any] | None = None,
) -> list[Any]:
    """``[function(job) for job in jobs]`` computed in parallel (`for_each_result`)."""
    results: dict[int, Any] = {}
    for_each_result(
        function,
        jobs,
        results.__setitem__,
        workers=workers,
        backend=backend,
        progress=progress,
        label=label,
        describe=describe,
        crashed=crashed,
    )
    return [results[i] for i in range(len(jobs))]


@contextmanager
def single_threaded() -> Iterator[None]:
    """Single-threaded BLAS/OpenMP (and torch, if imported) in this process, and in the
    worker processes started inside this block (through the environment)."""
    saved = {key: os.environ.get(key) for key in SINGLE_THREAD_ENV}
    os.environ.update(SINGLE_THREAD_ENV)
    torch = sys.modules.get("torch")
    torch_threads = torch.get_num_threads() if torch is not None else None
    try:
        with threadpool_limits(limits=1):
            if torch is not None:
                torch.set_num_threads(1)
            yield
    finally:
        if torch is not None:
            torch.set_num_threads(torch_threads)
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def _call(function: Callable[[Any], Any], job: Any) -> Any:
    return function(job)


def worker_processes(workers: int, preload: Sequence[str] = ()) -> WorkerPool:
    """``workers`` processes that several `for_each_result` calls can share
    (``pool=``), so each worker starts (imports) once; a context manager that ends them.
    ``preload``: as for `for_each_result`."""
    return WorkerPool(workers, spawn_env=single_threaded, preload=preload)


def _run_processes(function, jobs, workers, settle, pool: WorkerPool | None, preload) -> None:
    own = worker_processes(workers, preload) if pool is None else contextlib.nullcontext(pool)
    with own as used:
        for index, ok, outcome in used.results(function, list(jobs), workers):
            settle(index, ok, outcome)


def _run_ray(function, jobs, workers, settle) -> None:
    try:
        import ray
    except ImportError:
        raise ImportError(
            "backend 'ray' needs the optional extra: pip install 'elastic-gym[ray]'"
        ) from None
    started = not ray.is_initialized()
    if started and os.environ.get("RAY_ADDRESS"):  # an existing cluster (its own CPUs)
        ray.init(
            address=os.environ["RAY_ADDRESS"],
            log_to_driver=False,
            runtime_env={"env_vars": SINGLE_THREAD_ENV},
        )
        workers = max(1, int(ray.cluster_resources().get("CPU", workers)))
    elif started:
        start_reaper()  # first: ends the local runtime if this process dies, even mid-start
        ray.init(
            num_cpus=workers,
            include_dashboard=False,
            log_to_driver=False,
            runtime_env={"env_vars": SINGLE_THREAD_ENV},
        )
    if started and _handlers_depth and threading.current_thread() is threading.main_thread():
        _install_handlers()  # ray.init installs a SIGTERM handler of its own
    # _call: ray.remote takes plain functions only; a crashed worker fails its task
    remote = ray.remote(num_cpus=1, max_retries=0)(_call)
    queue = iter(enumerate(jobs))
    pending: dict = {}
    try:
        while True:
            while len(pending) < RAY_IN_FLIGHT * workers and (item := next(queue, None)):
                pending[remote.remote(function, item[1])] = item[0]
            if not pending:
                break
            done, _ = ray.wait(list(pending), num_returns=1, timeout=RAY_POLL)
            for ref in done:
                index = pending.pop(ref)
                try:
                    ok, outcome = True, ray.get(ref)
                except ray.exceptions.WorkerCrashedError as exc:
                    ok, outcome = False, WorkerDiedError(None, f"the Ray worker crashed: {exc}")
                except Exception as exc:
                    ok, outcome = False, exc
                settle(index, ok, outcome)
    except BaseException:
        for ref in pending:
            with contextlib.suppress(Exception):  # e.g. a task that has just finished
                ray.cancel(ref, force=True)
        if started:
            ray.shutdown()
        raise
