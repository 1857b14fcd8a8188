"""CPU time of an env step in this tree against another checkout: a refactor's A/B.

    python benchmarks/step_ab.py OTHER_TREE [--rounds 8] [--blocks 15] [--steps 300]

Runs the same measurement alternately in processes importing ``elastic_gym`` from
``OTHER_TREE`` (A) and from this tree (B), ``--rounds`` times each, and prints, per case,
the best and the median over the rounds of each side and their ratio B / A. A case's value
in one process is the best of ``--blocks`` blocks of the CPU time of the process per
step (``time.process_time``: time other processes take the cores from it is not counted,
so the A/B holds on a loaded machine). Cases: the single env of three ids, a vector env of
8 and 64 arms (per arm-step) and a reset, all on the excitation task at rest (the cost of
a step does not depend on the motion).
"""

from __future__ import annotations

import argparse
import ast
import functools
import os
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent
KWARGS: dict = {"task": "excitation", "task_options": {"amplitude": 0.0}, "episode_time": None}
SINGLE = ("TwoLinkElastic-v0", "KR15Elastic-v0", "TwoLinkRigid-v0")
ARMS = (8, 64)


def _best(call, repeats: int, blocks: int) -> float:
    """The least CPU time of ``repeats`` calls of ``call`` over ``blocks`` blocks (s)."""
    import time

    best = float("inf")
    for _ in range(blocks):
        start = time.process_time()
        for _ in range(repeats):
            call()
        best = min(best, time.process_time() - start)
    return best


def measure(blocks: int, steps: int) -> dict[str, float]:
    """Per case, the CPU time of a step (per arm for a vector env) or a reset (us)."""
    import gymnasium as gym
    import numpy as np

    import elastic_gym  # noqa: F401 - registers the ids

    out = {}
    for name in SINGLE:
        env = gym.make(f"elastic_gym/{name}", **KWARGS)
        env.reset(seed=0)
        action = np.zeros(env.action_space.shape)
        for _ in range(200):
            env.step(action)
        step = functools.partial(env.step, action)
        out[f"{name} step"] = _best(step, steps, blocks) / steps * 1e6
        env.close()
    for n in ARMS:
        envs = gym.make_vec(
            "elastic_gym/TwoLinkElastic-v0", n, vectorization_mode="vector_entry_point", **KWARGS
        )
        envs.reset(seed=0)
        actions = np.zeros((n, 2))
        for _ in range(50):
            envs.step(actions)
        repeats = max(4 * steps // n, 20)
        step = functools.partial(envs.step, actions)
        per_arm = _best(step, repeats, blocks) / repeats / n * 1e6
        out[f"TwoLinkElastic-v0 {n} arms, per arm-step"] = per_arm
        envs.close()
    env = gym.make("elastic_gym/TwoLinkElastic-v0")
    env.reset(seed=0)
    out["TwoLinkElastic-v0 reset"] = _best(env.reset, 50, blocks) / 50 * 1e6
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("other", type=Path, help="the checkout to compare with (A)")
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--blocks", type=int, default=15)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        print(repr(measure(args.blocks, args.steps)))
        return 0
    trees = {"A": args.other.resolve(), "B": HERE}
    values: dict[str, list[dict[str, float]]] = {"A": [], "B": []}
    for _ in range(args.rounds):
        for side, tree in trees.items():
            env = {**os.environ, "PYTHONPATH": str(tree)}
            command = [sys.executable, __file__, str(tree), "--measure"]
            command += ["--blocks", str(args.blocks), "--steps", str(args.steps)]
            done = subprocess.run(command, env=env, cwd="/", capture_output=True, text=True)
            if done.returncode:
                sys.stderr.write(done.stderr)
                return done.returncode
            values[side].append(ast.literal_eval(done.stdout.strip().splitlines()[-1]))
    print(f"A: {trees['A']}\nB: {trees['B']}\n")
    print("| case | A best [us] | B best [us] | B / A | A median | B median | B / A |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for case in values["A"][0]:
        a = [v[case] for v in values["A"]]
        b = [v[case] for v in values["B"]]
        best_a, best_b = min(a), min(b)
        med_a, med_b = statistics.median(a), statistics.median(b)
        print(
            f"| {case} | {best_a:.1f} | {best_b:.1f} | {best_b / best_a:.3f} "
            f"| {med_a:.1f} | {med_b:.1f} | {med_b / med_a:.3f} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
