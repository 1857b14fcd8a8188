"""The execution of a comparison's plan: its worlds run in parallel, with recovery.

The second of the comparison's three stages (plan → execute → report). Each world of the
plan runs in [`run_group`][elastic_gym.evaluation.episodes.run_group], on worker
processes or Ray (``backend="ray"``, the same job function) through
`elastic_gym.runtime.parallel.for_each_result`, with a progress bar
counting runs. A world whose worker process dies (``os._exit``, a signal, a segmentation
fault in user code) is recovered by
[`crashed_results`][elastic_gym.evaluation.execute.crashed_results]: its runs run again one
per worker, so that only the run that kills its worker fails.

[`run_plan`][elastic_gym.evaluation.execute.run_plan] is the whole stage (workers, pre-run
check, runs handed to a [`ResultSink`][elastic_gym.evaluation.execute.ResultSink] as each
world ends); [`execute`][elastic_gym.evaluation.execute.execute] runs a list of runs and
returns their results in memory.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from typing import Protocol

from elastic_gym.evaluation.episodes import RunResult, failed_status, run_group
from elastic_gym.evaluation.grid import RunSpec
from elastic_gym.evaluation.groups import DEFAULT_BATCH_SIZE, RunGroup
from elastic_gym.evaluation.plan import Plan, group_runs
from elastic_gym.evaluation.preflight import Estimate, preflight
from elastic_gym.runtime.parallel import (
    DEFAULT_BACKEND,
    for_each_result,
    interrupts_raised,
    worker_processes,
)
from elastic_gym.runtime.process_pool import WorkerDiedError, WorkerPool, refers_to_main

OnResults = Callable[[int, list[RunResult]], None]  # (index of the world, its results)


def describe_group(group: RunGroup) -> str:
    """How a world is named in an error: its run's labels, or its first run's."""
    first = group.first.labels
    return f"run {first}" if len(group) == 1 else f"group of {len(group)} runs like {first}"


def crashed_results(group: RunGroup, exc: WorkerDiedError) -> list[RunResult]:
    """The rows of a world whose worker process died while running it: a run alone gets
    the failed row (no samples kept); a world of several runs runs each of them again in
    a worker process of its own, so that only the run that kills its worker fails and
    its batch mates get their rows."""
    if len(group) == 1:
        return [RunResult(group.first, failed_status(exc), {}, None, 0.0)]
    results: dict[int, RunResult] = {}
    for_each_result(
        run_group,
        [RunGroup((spec,)) for spec in group.runs],
        lambda _, alone: results.update((r.spec.index, r) for r in alone),
        workers=min(2, len(group)),
        progress=False,
        describe=describe_group,
        crashed=crashed_results,
    )
    return [results[spec.index] for spec in group.runs]


def run_groups(
    groups: Sequence[RunGroup],
    on_results: OnResults,
    workers: int,
    backend: str,
    progress: bool,
    pool: WorkerPool | None = None,
) -> None:
    """Run the worlds ``groups`` on ``workers`` processes (of ``pool`` when given) or Ray,
    calling ``on_results(index, results)`` as each ends (module docstring)."""
    for_each_result(
        run_group,
        groups,
        on_results,
        workers=workers,
        backend=backend,
        progress=progress,
        label="runs",
        describe=describe_group,
        crashed=crashed_results,
        size=len,
        pool=pool,
    )


def _workers(plan: Plan) -> contextlib.AbstractContextManager[WorkerPool | None]:
    """The worker processes that will run the plan, started now: the pool, or None where
    the runs need none (Ray; one worker for jobs that refer to ``__main__``, run in this
    process)."""
    groups = list(plan.groups)
    if plan.backend != "process" or (plan.workers == 1 and refers_to_main(run_group, groups)):
        return contextlib.nullcontext()
    # the pre-run check runs first on these workers; a check of its own after a death
    # forks from the same server (`fork_server`: a server serves what it preloaded)
    pool = worker_processes(min(plan.workers, len(groups)), preload=[preflight.__module__])
    pool.start(run_group, groups)
    return pool


class ResultSink(Protocol):
    """Where an execution delivers: ``start`` once the pre-run check passed (with the
    estimated duration), ``add`` as each world ends, ``interrupted`` with what ended the
    runs (returns the exception to raise, saying what was kept)."""

    def start(self, estimate: Estimate) -> None: ...

    def add(self, index: int, results: list[RunResult]) -> None: ...

    def interrupted(self, exc: BaseException) -> BaseException: ...


class Execution:
    """The execute stage of a [`Plan`][elastic_gym.evaluation.plan.Plan], for a ``with``
    block: the worker processes start on entry (so that the pre-run check runs in one of
    them while the others start) and end on exit, however the block ends.

    Args:
        plan: what runs, in which worlds, on how many workers.
    """

    def __init__(self, plan: Plan) -> None:
        self.plan = plan
        self._pool: WorkerPool | None = None
        self._stack = contextlib.ExitStack()

    def __enter__(self) -> Execution:
        self._pool = self._stack.enter_context(_workers(self.plan))
        return self

    def __exit__(self, *exc_info) -> None:
        self._pool = None
        self._stack.__exit__(*exc_info)

    def check(self) -> Estimate:
        """Build once what the runs will build, in a worker
        ([`preflight`][elastic_gym.evaluation.preflight.preflight]): raises `ScenarioError`
        naming the field that cannot work; returns the estimated wall time. A real Ctrl-C
        is not taken for the sampled user code's own."""
        with interrupts_raised():
            plan = self.plan
            return preflight(plan.scenario, plan.groups, plan.workers, self._pool, plan.backend)

    def run(self, on_results: OnResults, progress: bool = True) -> None:
        """Run every world, calling ``on_results(index, results)`` as each ends."""
        plan = self.plan
        run_groups(plan.groups, on_results, plan.workers, plan.backend, progress, self._pool)


def run_plan(plan: Plan, sink: ResultSink, progress: bool = True) -> None:
    """The whole execute stage: workers started, the pre-run check, then every world, its
    results handed to ``sink`` as it ends; what ends the runs (an interrupt, a full disk)
    is raised as ``sink.interrupted`` makes it."""
    with Execution(plan) as execution:
        sink.start(execution.check())
        try:
            execution.run(sink.add, progress)
        except BaseException as exc:
            raise sink.interrupted(exc)  # noqa: B904 - the sink sets the cause


def execute(
    runs: Sequence[RunSpec],
    workers: int | None = None,
    backend: str = DEFAULT_BACKEND,
    progress: bool = True,
    batch_size: int = DEFAULT_BATCH_SIZE,
) -> list[RunResult]:
    """Run all episodes in parallel, grouped into worlds of at most ``batch_size`` arms
    ([`group_runs`][elastic_gym.evaluation.plan.group_runs]); the results in run order.

    ``workers=1`` with the process backend runs in one worker process (in this one, with
    single-threaded BLAS, when the runs refer to classes of ``__main__``:
    `elastic_gym.runtime.parallel.for_each_result`). Every result stays
    in memory with its time series; [`compare`][elastic_gym.evaluation.compare.compare]
    streams them to disk instead.
    """
    groups, n_workers = group_runs(runs, workers, backend, batch_size)
    results: dict[int, RunResult] = {}
    run_groups(
        groups,
        lambda _, group_results: results.update((r.spec.index, r) for r in group_results),
        n_workers,
        backend,
        progress,
    )
    return [results[spec.index] for spec in runs]
