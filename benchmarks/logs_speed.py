"""Speed of the offline tools on a recorded log: `elastic-gym observe` (De Luca's observer
over a 60 s, 1 kHz TwoLinkElastic log) against real time.

    python benchmarks/logs_speed.py [--duration 60] [--log LOG.csv] [--repeats 3]

Records the identification excitation (`record_excitation`, seed 0) unless `--log` gives
one, then times `estimate_log` on it (blocks, best kept: CPU time of this process, and
wall time) and reports the real-time factor (log seconds per second of computation), the
cost per sample, and the cost of one online update of the same observer (the wrappers'
per-step call). It also checks that the offline estimate equals one `update` per sample,
bit for bit.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from timing import ensure_single_thread_blas, machine_line, print_table

OBSERVERS = ("deluca", "finite-difference")


def recorded_log(duration: float, folder: Path) -> Path:
    from elastic_gym.logs import write_log
    from elastic_gym.logs.record import record_excitation

    log, _ = record_excitation("TwoLinkElastic-v0", duration, seed=0)
    return write_log(folder / "excitation.csv", log)[0]


def time_observe(log, name: str, repeats: int) -> tuple[float, float, np.ndarray]:
    """Best CPU and wall seconds of `estimate_log` over `repeats` runs, and its estimate."""
    from elastic_gym.logs import estimate_log

    estimate_log(log, name)  # compiled kernels loaded, caches warm
    best_cpu = best_wall = float("inf")
    result = None
    for _ in range(repeats):
        cpu, wall = time.process_time(), time.perf_counter()
        result = estimate_log(log, name)
        best_cpu = min(best_cpu, time.process_time() - cpu)
        best_wall = min(best_wall, time.perf_counter() - wall)
    assert result is not None
    return best_cpu, best_wall, result.estimate


def stepwise(log, name: str, samples: int) -> tuple[float, np.ndarray]:
    """CPU seconds per online `update` (the wrappers' call) and the estimates of the first
    `samples` rows, one update per row."""
    from elastic_gym.observers.estimation import Estimator
    from elastic_gym.observers.registry import make_observer

    estimator = Estimator(make_observer(name, log.nominal_model(), log.sample_time), 1)
    observed = {key: value[:, None] for key, value in log.observations().items()}
    estimator.reset({k: v[0] for k, v in observed.items()}, np.array([0]))
    rows = [estimator.estimates[0].copy()]
    arms = np.array([0])
    start = time.process_time()
    for k in range(1, samples):
        measured = {key: value[k] for key, value in observed.items()}
        estimator.update(measured, log.torque[k - 1][None], log.sample_time, arms)
        rows.append(estimator.estimates[0].copy())
    return (time.process_time() - start) / (samples - 1), np.array(rows)


def main() -> None:
    ensure_single_thread_blas()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, help="s of log to record")
    parser.add_argument("--log", help="an existing log instead of recording one")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--stepwise-samples", type=int, default=5000)
    args = parser.parse_args()

    from elastic_gym import __version__
    from elastic_gym.logs import read_log

    print(f"elastic-gym {__version__}, {machine_line()}")
    with tempfile.TemporaryDirectory() as folder:
        path = Path(args.log) if args.log else recorded_log(args.duration, Path(folder))
        log = read_log(path)
        rows = []
        for name in OBSERVERS:
            cpu, wall, estimate = time_observe(log, name, args.repeats)
            per_update, online = stepwise(log, name, min(args.stepwise_samples, len(log)))
            equal = np.array_equal(online, estimate[: len(online)])
            rows.append(
                (
                    name,
                    len(log),
                    f"{log.duration:.1f}",
                    f"{cpu:.3f}",
                    f"{wall:.3f}",
                    f"{log.duration / cpu:.0f}x",
                    f"{log.duration / wall:.0f}x",
                    f"{cpu / len(log) * 1e6:.1f}",
                    f"{per_update * 1e6:.1f}",
                    "yes" if equal else "NO",
                )
            )
        print_table(
            f"observe on {path.name}: real-time factor = log seconds / seconds of computation "
            f"(best of {args.repeats}); load average at the end: {machine_line()}",
            (
                "observer",
                "samples",
                "log s",
                "CPU s",
                "wall s",
                "x real time (CPU)",
                "x real time (wall)",
                "µs/sample offline",
                "µs/update online",
                "offline = online",
            ),
            rows,
        )


if __name__ == "__main__":
    main()
