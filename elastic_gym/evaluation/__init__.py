"""Evaluation: compare controllers on full-state control with estimated versus true state.

The input is a [`Scenario`][elastic_gym.evaluation.scenario.Scenario] (the grid: envs x
robustness axes x model errors x seeds x controllers x state sources; shipped presets in
`elastic_gym.evaluation.presets`). Then three stages, data
flowing one way:

* plan — [`elastic_gym.evaluation.plan`][elastic_gym.evaluation.plan]: runs grouped into
  worlds, plain data;
* execute — [`elastic_gym.evaluation.execute`][elastic_gym.evaluation.execute]: worlds,
  closed loop, pre-run check, worker processes and recovery;
* report — [`elastic_gym.evaluation.report`][elastic_gym.evaluation.report]: output folder,
  tables, figures, sweep curves and margins.

[`compare`][elastic_gym.evaluation.compare.compare] runs the three, as ``elastic-gym compare``.
"""

from elastic_gym.evaluation.compare import Comparison, compare
from elastic_gym.evaluation.episodes import RunResult, run_episode, run_group
from elastic_gym.evaluation.execute import execute
from elastic_gym.evaluation.grid import RunSpec, plan_runs
from elastic_gym.evaluation.groups import RunGroup
from elastic_gym.evaluation.metrics import TimeSeries, compute_metrics
from elastic_gym.evaluation.plan import Plan, make_plan
from elastic_gym.evaluation.presets import list_presets, load_preset, load_scenario
from elastic_gym.evaluation.scenario import (
    ControllerEntry,
    EnvEntry,
    Scenario,
    ScenarioError,
    SourceEntry,
    Variation,
)

__all__ = [
    "Comparison",
    "ControllerEntry",
    "EnvEntry",
    "Plan",
    "RunGroup",
    "RunResult",
    "RunSpec",
    "Scenario",
    "ScenarioError",
    "SourceEntry",
    "TimeSeries",
    "Variation",
    "compare",
    "compute_metrics",
    "execute",
    "list_presets",
    "load_preset",
    "load_scenario",
    "make_plan",
    "plan_runs",
    "run_episode",
    "run_group",
]
