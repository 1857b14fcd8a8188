"""Regenerate the shipped leaderboard of the elastic-gym benchmark.

    python studies/leaderboard.py                   # score every shipped entry, rebuild
    python studies/leaderboard.py --entries eq13@deluca motor-pd@finite-difference
    python studies/leaderboard.py --train           # first train the RL baselines
    python studies/leaderboard.py --rebuild         # only rebuild docs/leaderboard.md

1. ``--train``: the RL baselines' run folders (``runs/benchmark/<name>``) with
   ``elastic-gym train``'s defaults and fixed training seeds (``RL_BASELINES``): pure PPO
   on the De Luca estimate and the residual PPO on eq. (13), also on the De Luca estimate.
   Training seeds are 0 .. n_envs - 1 (and 10 000 + k for the learning curve): never the
   suite's evaluation seeds (90 000 ..). RecurrentPPO on the raw sensors
   is not among them: the comparison runner feeds a controller a state source's estimate,
   and a policy on raw sensors has none (``trained-policy`` refuses such a run).
2. Scoring: every entry of ``CLASSICAL`` (and every RL baseline whose run folder exists)
   with :func:`elastic_gym.benchmark.run_benchmark` on the whole suite, one entry after
   the other on all CPUs; each writes ``benchmark_out/<entry>/`` and its scorecard JSON is
   copied to ``docs/leaderboard/scorecards/<entry>.json``.
3. ``elastic-gym benchmark --leaderboard``: ``docs/leaderboard.md``, ``.csv`` and ``.png``
   from the scorecards in the repository.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from elastic_gym.benchmark import rebuild_leaderboard, run_benchmark
from elastic_gym.benchmark.leaderboard import SCORECARD_DIR

EQ13, INTEGRAL = "feedforward-state-feedback", "integral-state-feedback"
CLASSICAL = {
    "eq13@deluca": {"controller": EQ13, "source": "deluca"},
    "eq13@ekf": {"controller": EQ13, "source": "ekf"},
    "eq13@finite-difference": {"controller": EQ13, "source": "finite-difference"},
    "eq13-integral@deluca": {"controller": INTEGRAL, "source": "deluca"},
    "eq13-integral@ekf": {"controller": INTEGRAL, "source": "ekf"},
    "eq13-integral-loadid@deluca": {
        "controller": INTEGRAL,
        "source": "deluca",
        "options": {"load_identification": "shared"},
    },
    "motor-pd@finite-difference": {"controller": "motor-pd", "source": "finite-difference"},
    "link-pd@deluca": {"controller": "link-pd", "source": "deluca"},
    # oracle references: the same laws on the true state
    "eq13@true": {"controller": EQ13, "source": "true"},
    "eq13-integral@true": {"controller": INTEGRAL, "source": "true"},
    "eq13-integral-loadid@true": {
        "controller": INTEGRAL,
        "source": "true",
        "options": {"load_identification": "shared"},
    },
    "motor-pd@true": {"controller": "motor-pd", "source": "true"},
    "link-pd@true": {"controller": "link-pd", "source": "true"},
}
RUNS = Path("runs/benchmark")
RL_BASELINES = {  # name -> elastic-gym train arguments (seed 0, the shipped defaults)
    "ppo@deluca": ["--algo", "ppo", "--state", "deluca"],
    "residual-ppo@deluca": ["--algo", "ppo", "--state", "deluca", "--residual", EQ13],
}


def train_baselines(names: list[str]) -> None:
    from elastic_gym.cli import main

    for name in names:
        folder = RUNS / name
        if (folder / "config.yaml").exists():
            print(f"{name}: {folder} exists, not retrained")
            continue
        main(["train", *RL_BASELINES[name], "--seeds", "0", "--out", str(folder)])


def score(names: list[str], workers: int | None) -> None:
    SCORECARD_DIR.mkdir(parents=True, exist_ok=True)
    for name in names:
        entry = CLASSICAL.get(name) or {"run": str(RUNS / name)}
        out = Path("benchmark_out") / name
        card = run_benchmark(
            {**entry, "label": name}, output_dir=out, overwrite=True, workers=workers
        )
        shutil.copy(out / "scorecard.json", SCORECARD_DIR / f"{name}.json")
        print(f"{name}: {card.scores.overall:.3f} in {card.wall_time:.0f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--entries", nargs="+", help="score only these entries")
    parser.add_argument("--train", action="store_true", help="train the RL baselines first")
    parser.add_argument("--rebuild", action="store_true", help="only rebuild the leaderboard")
    parser.add_argument("--workers", type=int)
    args = parser.parse_args()
    rl = [n for n in RL_BASELINES if (RUNS / n / "config.yaml").exists() or args.train]
    names = args.entries or [*CLASSICAL, *rl]
    if not args.rebuild:
        if args.train:
            train_baselines([n for n in names if n in RL_BASELINES])
        score(names, args.workers)
    rebuild_leaderboard()


if __name__ == "__main__":
    main()
