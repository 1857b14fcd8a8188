"""The plan of a comparison: its runs, grouped into worlds, and the workers that run them.

The first of the comparison's three stages (plan → execute → report). A
[`Plan`][elastic_gym.evaluation.plan.Plan] is plain data: nothing is built, no process is
started. It is made of the grid's runs
([`plan_runs`][elastic_gym.evaluation.grid.plan_runs]; the combinations that do not apply
are kept with their reason), the worlds they share
([`plan_groups`][elastic_gym.evaluation.groups.plan_groups]: at most ``batch_size`` arms
each, at least two worlds per worker while that splits them) and the number of workers
(`elastic_gym.runtime.parallel.resolve_workers`: by default one per
CPU, at most one per run). The execute stage
([`elastic_gym.evaluation.execute`][elastic_gym.evaluation.execute]) takes it from there.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from elastic_gym.evaluation.grid import RunSpec, SkippedRun, plan_runs
from elastic_gym.evaluation.groups import DEFAULT_BATCH_SIZE, RunGroup, plan_groups
from elastic_gym.evaluation.scenario import Scenario
from elastic_gym.runtime.parallel import DEFAULT_BACKEND, resolve_workers
from elastic_gym.validation import checked_count


@dataclass(frozen=True)
class Plan:
    """What a comparison runs: every run once in ``runs`` (run order) and once in
    ``groups`` (its world), the combinations ``skipped``, and where they run (``workers``
    processes of ``backend``)."""

    scenario: Scenario
    runs: tuple[RunSpec, ...]
    skipped: tuple[SkippedRun, ...]
    groups: tuple[RunGroup, ...]
    workers: int
    backend: str

    def __str__(self) -> str:
        worlds, workers = len(self.groups), self.workers
        return (
            f"{len(self.runs)} runs in {worlds} {'world' if worlds == 1 else 'worlds'} on "
            f"{workers} {'worker' if workers == 1 else 'workers'}"
        )

    @property
    def skipped_note(self) -> str:
        """One line per reason: how many combinations were skipped as not applicable."""
        counts: dict[str, int] = {}
        for run in self.skipped:
            counts[run.reason] = counts.get(run.reason, 0) + 1
        return "".join(f"skipped {n} runs: {reason}\n" for reason, n in counts.items())


def group_runs(
    runs: Sequence[RunSpec],
    workers: int | None = None,
    backend: str = DEFAULT_BACKEND,
    batch_size: int = DEFAULT_BATCH_SIZE,
) -> tuple[tuple[RunGroup, ...], int]:
    """The worlds of ``runs`` and the number of workers that run them (module docstring);
    ``ValueError`` for a ``batch_size`` below 1 or a bad ``workers``."""
    checked_count(batch_size, "batch_size", 1)
    n_workers = resolve_workers(workers, len(runs), backend)
    return tuple(plan_groups(runs, batch_size, n_workers)), n_workers


def make_plan(
    scenario: Scenario,
    workers: int | None = None,
    backend: str = DEFAULT_BACKEND,
    batch_size: int = DEFAULT_BATCH_SIZE,
) -> Plan:
    """The plan of ``scenario`` (module docstring).

    Raises `ScenarioError` naming the field of a controller or state source that cannot
    be built with its options, ``ValueError`` when no run applies or for a bad
    ``workers`` or ``batch_size``.
    """
    runs, skipped = plan_runs(scenario)
    if not runs:
        raise ValueError(
            f"scenario {scenario.name!r} has no applicable run "
            f"({len(skipped)} combinations skipped: {skipped[:3]})"
        )
    groups, n_workers = group_runs(runs, workers, backend, batch_size)
    return Plan(scenario, tuple(runs), tuple(skipped), groups, n_workers, backend)
