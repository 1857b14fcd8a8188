"""Evaluation: compare controllers on full-state control with estimated versus true state.

* :mod:`~elastic_gym.evaluation.scenario` — the grid (envs x robustness axes x model
  errors x seeds x controllers x state sources) and its validation, on the models of
  :mod:`~elastic_gym.evaluation.scenario_models` and
  :mod:`~elastic_gym.evaluation.magnitudes`; :mod:`~elastic_gym.evaluation.presets` —
  the shipped presets and YAML files;
* :mod:`~elastic_gym.evaluation.runner` — one episode and the parallel execution;
* :mod:`~elastic_gym.evaluation.metrics` — metric definitions;
* :mod:`~elastic_gym.evaluation.report` and :mod:`~elastic_gym.evaluation.plots` — tables, PNGs;
* :func:`compare` — all of it, as ``elastic-gym compare`` does.
"""

from elastic_gym.evaluation.compare import Comparison, compare
from elastic_gym.evaluation.metrics import TimeSeries, compute_metrics
from elastic_gym.evaluation.presets import list_presets, load_preset, load_scenario
from elastic_gym.evaluation.runner import RunResult, RunSpec, execute, plan_runs, run_episode
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
    "plan_runs",
    "run_episode",
]
