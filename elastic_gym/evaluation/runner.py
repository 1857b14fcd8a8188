"""Former home of the comparison's runs, kept so that earlier imports keep working.

The comparison is now three stages, each in its own modules (see the CHANGELOG):
plan ([`elastic_gym.evaluation.grid`][elastic_gym.evaluation.grid],
[`elastic_gym.evaluation.groups`][elastic_gym.evaluation.groups],
[`elastic_gym.evaluation.plan`][elastic_gym.evaluation.plan]), execute
([`elastic_gym.evaluation.world`][elastic_gym.evaluation.world],
[`elastic_gym.evaluation.closed_loop`][elastic_gym.evaluation.closed_loop],
[`elastic_gym.evaluation.episodes`][elastic_gym.evaluation.episodes],
[`elastic_gym.evaluation.execute`][elastic_gym.evaluation.execute]) and report. Import from
those modules, or the public names from `elastic_gym.evaluation`; this module will be
removed.
"""

from __future__ import annotations

from elastic_gym.evaluation.closed_loop import STATUS_OK, ClosedLoop
from elastic_gym.evaluation.episodes import (
    RunResult,
    describe_failure,
    failed_status,
    run_episode,
    run_group,
)
from elastic_gym.evaluation.execute import crashed_results, describe_group, execute
from elastic_gym.evaluation.grid import RunSpec, SkippedRun, check_options, plan_runs
from elastic_gym.evaluation.world import (
    World,
    arm_env,
    arm_vector_env,
    build_observer_wrapper,
    build_vector_controller,
    build_world,
    make_group_env,
    run_model,
)

__all__ = [
    "STATUS_OK",
    "ClosedLoop",
    "RunResult",
    "RunSpec",
    "SkippedRun",
    "World",
    "arm_env",
    "arm_vector_env",
    "build_observer_wrapper",
    "build_vector_controller",
    "build_world",
    "check_options",
    "crashed_results",
    "describe_failure",
    "describe_group",
    "execute",
    "failed_status",
    "make_group_env",
    "plan_runs",
    "run_episode",
    "run_group",
    "run_model",
]
