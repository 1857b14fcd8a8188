"""The elastic-gym benchmark: a versioned suite that scores any controller, observer or policy.

* :mod:`~elastic_gym.benchmark.suite` — the suite as data, validated and content-hashed;
* :mod:`~elastic_gym.benchmark.entry` — what is scored (controller + state source, a run
  folder, a callable policy); oracle references apart;
* :mod:`~elastic_gym.benchmark.scoring` — per-episode pass/fail, category, precision, overall;
* :mod:`~elastic_gym.benchmark.run` — :func:`run_benchmark` on the comparison runner;
* :mod:`~elastic_gym.benchmark.scorecard` / :mod:`~elastic_gym.benchmark.leaderboard`.

Python API::

    from elastic_gym.benchmark import run_benchmark

    card = run_benchmark({"controller": "feedforward-state-feedback", "source": "deluca"})
"""

from elastic_gym.benchmark.entry import Entry
from elastic_gym.benchmark.leaderboard import rebuild_leaderboard
from elastic_gym.benchmark.run import run_benchmark
from elastic_gym.benchmark.scorecard import Scorecard, read_scorecard
from elastic_gym.benchmark.suite import SuiteConfig, load_suite, suite_schema

__all__ = [
    "Entry",
    "Scorecard",
    "SuiteConfig",
    "load_suite",
    "read_scorecard",
    "rebuild_leaderboard",
    "run_benchmark",
    "suite_schema",
]
