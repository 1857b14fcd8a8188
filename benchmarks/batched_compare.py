"""``compare`` of one grid batched against one arm per world (bench.py table 7).

The grid: TwoLinkElastic tracking, eq. (13) and motor PD on the true state and on the De
Luca estimate, ``SEEDS`` seeds: 4 groups of ``SEEDS`` runs that may share a world. Both
ways run their worlds in this process (``run_group``, single-threaded BLAS), the CPU time
of the whole execution measured (world set-up, closed loop and metrics), the best of
interleaved repeats.
"""

from __future__ import annotations

import time

from elastic_gym.evaluation import Scenario, plan_runs
from elastic_gym.evaluation.episodes import run_group
from elastic_gym.evaluation.groups import DEFAULT_BATCH_SIZE, plan_groups
from elastic_gym.runtime.parallel import single_threaded

SEEDS = 16
DURATION = 0.5  # s per run
TARGET = {5e-4: 8.0, 6.25e-5: 2.5}  # speed-up targets at 0.5 ms and 1/16 ms physics


def grid(physics_dt: float, seeds: int, duration: float) -> Scenario:
    return Scenario.from_dict(
        {
            "name": "bench-compare",
            "duration": duration,
            "physics_dt": physics_dt,
            "seeds": list(range(seeds)),
            "envs": [{"id": "TwoLinkElastic-v0", "kwargs": {"task": "tracking"}}],
            "controllers": ["feedforward-state-feedback", "motor-pd"],
            "state_sources": [True, "deluca"],
        }
    )


def compare_costs(physics_dt: float, seeds: int, duration: float, repeats: int) -> dict:
    """CPU seconds of the grid's execution with ``batch_size`` 1 and the default."""
    runs, _ = plan_runs(grid(physics_dt, seeds, duration))
    best = {1: float("inf"), DEFAULT_BATCH_SIZE: float("inf")}
    for _ in range(repeats):
        for batch_size in best:
            start = time.process_time()
            with single_threaded():
                for group in plan_groups(runs, batch_size, 1):
                    run_group(group)
            best[batch_size] = min(best[batch_size], time.process_time() - start)
    return {"runs": len(runs), "alone": best[1], "batched": best[DEFAULT_BATCH_SIZE]}
