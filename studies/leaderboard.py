"""Regenerate the shipped leaderboard of the elastic-gym benchmark from the cards' commands.

    python studies/leaderboard.py                   # re-score every shipped card, rebuild
    python studies/leaderboard.py --entries eq13@deluca motor-pd@finite-difference
    python studies/leaderboard.py --rebuild         # only rebuild docs/leaderboard.md
    python studies/leaderboard.py --suite elastic-gym-v2   # move every card to another suite

Every card in ``docs/leaderboard/scorecards/`` records the ``elastic-gym benchmark`` command
that scores its entry (run from the repository's root). This script runs that command with
``--output benchmark_out/<label> --overwrite``, copies the new card over the old one, and
rebuilds the page, CSV and figure (``elastic-gym benchmark --leaderboard``). A new entry is
scored once by hand (docs/benchmark.md) and its card copied in; from then on it is
re-scored here. The RL entries' policies are exported policies in
``docs/leaderboard/runs/`` (``policy.onnx`` and its manifest ``policy.json``: no pickle),
trained by the commands of ``docs/leaderboard/runs/COMMANDS.txt`` (training seeds 0 ..,
never the suite's evaluation seeds 90 000 ..) and exported with ``elastic-gym export``.
"""

from __future__ import annotations

import argparse
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

from elastic_gym.benchmark import read_scorecard
from elastic_gym.benchmark.leaderboard import SCORECARD_DIR

OUTPUT = Path("benchmark_out")


def elastic_gym(args: list[str]) -> None:
    """Run the console script (this interpreter's package) or stop with its exit code."""
    print("$ elastic-gym " + shlex.join(args), flush=True)
    done = subprocess.run([sys.executable, "-m", "elastic_gym.cli", *args], check=False)
    if done.returncode:
        sys.exit(done.returncode)


def on_suite(words: list[str], suite: str | None) -> list[str]:
    """A card's command words with ``--suite`` replaced by ``suite`` (None: as recorded)."""
    if suite is None:
        return words
    at = words.index("--suite")
    return [*words[:at], "--suite", suite, *words[at + 2 :]]


def rescore(names: list[str], workers: int | None, suite: str | None) -> None:
    for name in names:
        path = SCORECARD_DIR / f"{name}.json"
        card = read_scorecard(path)
        if card.command is None:
            print(f"{name}: the card records no command (a Python callable); not re-scored")
            continue
        out = OUTPUT / name
        extra = ["--output", str(out), "--overwrite", "--no-progress"]
        extra += ["--workers", str(workers)] if workers else []
        elastic_gym([*on_suite(shlex.split(card.command)[1:], suite), *extra])
        shutil.copy(out / "scorecard.json", path)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--entries", nargs="+", metavar="LABEL", help="re-score only these")
    parser.add_argument("--rebuild", action="store_true", help="only rebuild the leaderboard")
    parser.add_argument("--workers", type=int)
    parser.add_argument("--suite", help="re-score on this suite instead of the cards' own")
    args = parser.parse_args()
    names = args.entries or sorted(p.stem for p in SCORECARD_DIR.glob("*.json"))
    missing = [n for n in names if not (SCORECARD_DIR / f"{n}.json").exists()]
    if missing:
        parser.error(f"--entries: no card {missing} in {SCORECARD_DIR}")
    if not args.rebuild:
        rescore(names, args.workers, args.suite)
    elastic_gym(["benchmark", "--leaderboard", *(["--suite", args.suite] if args.suite else [])])


if __name__ == "__main__":
    main()
