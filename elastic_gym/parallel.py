"""Run independent jobs in parallel: local worker processes or a Ray cluster, one code path.

Used by the comparison runner (one job = one episode) and by multi-seed training (one
job = one training run). Workers run single-threaded BLAS: on small matrices, OpenBLAS
threads competing for 2 cores made ``scipy.linalg.expm`` of a 16 x 16 matrix 300 x slower.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from typing import Any

from rich.progress import Progress

BACKENDS = ("process", "ray")
SINGLE_THREAD_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def default_workers(n_jobs: int) -> int:
    return max(1, min(n_jobs, os.cpu_count() or 1))


def run_jobs(
    function: Callable[[Any], Any],
    jobs: Sequence[Any],
    workers: int | None = None,
    backend: str = "process",
    progress: bool = True,
    label: str = "jobs",
    describe: Callable[[Any], str] = repr,
) -> list[Any]:
    """``[function(job) for job in jobs]`` computed in parallel, in the order of ``jobs``.

    ``backend="process"``: spawned worker processes (``workers=1``: in this process).
    ``backend="ray"``: a local Ray runtime with ``workers`` CPUs is started unless
    ``ray.init`` was already called (then the existing cluster is used). The first
    failing job cancels the others and raises ``RuntimeError`` naming it (``describe``).
    ``function`` and the jobs must be picklable (module-level function, plain data).
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; valid: {list(BACKENDS)}")
    if workers is not None and (not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    workers = workers or default_workers(len(jobs))
    results: dict[int, Any] = {}
    with Progress(disable=not progress, transient=False) as bar:
        task = bar.add_task(label, total=len(jobs))

        def collect(index: int, result: Any) -> None:
            results[index] = result
            bar.advance(task)

        def failure(index: int, exc: Exception) -> RuntimeError:
            return RuntimeError(f"{describe(jobs[index])} could not run: "
                                f"{type(exc).__name__}: {exc}")

        if backend == "ray":
            _run_ray(function, jobs, workers, collect, failure)
        elif workers == 1:
            for index, job in enumerate(jobs):
                try:
                    collect(index, function(job))
                except Exception as exc:
                    raise failure(index, exc) from exc
        else:
            _run_processes(function, jobs, workers, collect, failure)
    return [results[i] for i in range(len(jobs))]


@contextmanager
def single_thread_blas() -> Iterator[None]:
    """Single-threaded BLAS in the worker processes spawned inside this block."""
    saved = {key: os.environ.get(key) for key in SINGLE_THREAD_ENV}
    os.environ.update(SINGLE_THREAD_ENV)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def _run_processes(function, jobs, workers, collect, failure) -> None:
    context = multiprocessing.get_context("spawn")
    with single_thread_blas(), ProcessPoolExecutor(max_workers=workers,
                                                   mp_context=context) as pool:
        futures: dict[Future, int] = {pool.submit(function, job): i for i, job in enumerate(jobs)}
        for future in as_completed(futures):
            index = futures[future]
            try:
                collect(index, future.result())
            except Exception as exc:
                for other in futures:
                    other.cancel()
                raise failure(index, exc) from exc


def _run_ray(function, jobs, workers, collect, failure) -> None:
    try:
        import ray
    except ImportError:
        raise ImportError("backend 'ray' needs the optional extra: pip install "
                          "'elastic-gym[ray]'") from None
    if not ray.is_initialized():
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False,
                 runtime_env={"env_vars": SINGLE_THREAD_ENV})
    remote = ray.remote(num_cpus=1)(function)
    pending = {remote.remote(job): i for i, job in enumerate(jobs)}
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        index = pending.pop(done[0])
        try:
            collect(index, ray.get(done[0]))
        except Exception as exc:
            for ref in pending:
                ray.cancel(ref)
            raise failure(index, exc) from exc
