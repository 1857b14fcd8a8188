"""The elastic-gym benchmark: a versioned suite that scores any controller, observer or policy.

* `suite` — the suite as data, validated and content-hashed;
* `entry` — what is scored (controller + state source, a run folder, a callable policy);
  `command` — the command line that names an entry;
* `scoring` — per-episode pass/fail, category, precision, overall;
* `run` — `run_benchmark` on the comparison runner; `verify` — a card re-run and compared;
* `card` (the scorecard as data), `audit` (a card checked against its suite),
  `scorecard` (its files), `leaderboard` and `page` (the ranking rebuilt from cards).

Python API::

    from elastic_gym.benchmark import run_benchmark

    card = run_benchmark({"controller": "feedforward-state-feedback", "source": "deluca"})
"""

from elastic_gym.benchmark.card import Scorecard, read_scorecard
from elastic_gym.benchmark.entry import Entry
from elastic_gym.benchmark.leaderboard import rebuild_leaderboard
from elastic_gym.benchmark.run import run_benchmark
from elastic_gym.benchmark.suite import SuiteConfig, load_suite, suite_schema
from elastic_gym.benchmark.verify import verify_card

__all__ = [
    "Entry",
    "Scorecard",
    "SuiteConfig",
    "load_suite",
    "read_scorecard",
    "rebuild_leaderboard",
    "run_benchmark",
    "suite_schema",
    "verify_card",
]
