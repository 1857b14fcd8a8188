"""Time to the first step: what numba's compile costs a fresh install, and what its cache saves.

Per env id, two fresh processes share one new, empty numba cache folder
(``NUMBA_CACHE_DIR``): the first compiles every kernel its first step needs (cold), the
second loads them from the cache (warm). Each times ``import elastic_gym`` and then
``gym.make`` + ``reset`` + one step, CPU and wall. The cold process also records each
kernel's own compile time (numba's compile events, the callees' own compiles taken out)
and the part of it in LLVM's lock (optimisation and machine code): a kernel that only
calls others and spends most of its own time in LLVM is optimising its callees' code
again, which numba links into every caller.

    python benchmarks/first_step.py [--ids ID ...] [--top 12]

Runs each id alone (a cold cache per id: ids share most kernels); about a minute per id
on 2 cores. Prints the load average with the tables: other processes only add time.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

CHILD = "--child"


def _kernel_recorder() -> tuple[Counter, Counter, Counter]:
    """Own compile time, own LLVM time and compile count per kernel, filled by numba's
    events as kernels compile in this process (a callee compiled inside its caller's
    compile is charged to the callee only)."""
    from numba.core import event

    own, llvm, count = Counter(), Counter(), Counter()
    stack: list[list] = []  # [name, start, time in nested compiles]
    locked: list[float] = []  # the starts of the LLVM lock's (re-entrant) acquisitions

    class Compiles(event.Listener):
        def on_start(self, ev):
            stack.append([ev.data["dispatcher"].py_func.__qualname__, time.process_time(), 0.0])

        def on_end(self, ev):
            name, start, nested = stack.pop()
            spent = time.process_time() - start
            own[name] += spent - nested
            count[name] += 1
            if stack:
                stack[-1][2] += spent

    class LLVMLock(event.Listener):
        def on_start(self, ev):
            locked.append(time.process_time())

        def on_end(self, ev):
            start = locked.pop()
            if stack and not locked:  # the outermost hold, charged to the innermost kernel
                llvm[stack[-1][0]] += time.process_time() - start

    event.register("numba:compile", Compiles())
    event.register("numba:llvm_lock", LLVMLock())
    return own, llvm, count


def child(env_id: str) -> None:
    """One fresh process: import, first step, per-kernel compile times (JSON on stdout)."""
    wall, cpu = time.perf_counter(), time.process_time()
    import gymnasium as gym

    import elastic_gym  # noqa: F401 - registers the ids (imported by nothing before)

    imported = time.perf_counter() - wall, time.process_time() - cpu
    own, llvm, count = _kernel_recorder()
    wall, cpu = time.perf_counter(), time.process_time()
    env = gym.make(env_id)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    first = time.perf_counter() - wall, time.process_time() - cpu
    env.close()
    kernels = {name: (own[name], llvm[name], count[name]) for name in own}
    print(json.dumps({"import": imported, "first": first, "kernels": kernels}))


def run_child(env_id: str, cache: Path) -> dict:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    done = subprocess.run(
        [sys.executable, __file__, CHILD, env_id],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    from timing import machine_line, print_table

    import elastic_gym

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ids", nargs="+", default=list(elastic_gym.ENV_IDS))
    parser.add_argument("--top", type=int, default=12, help="kernels listed per id")
    args = parser.parse_args()
    print(f"elastic-gym {elastic_gym.__version__}; {machine_line()}\n")
    rows, kernels = [], {}
    for env_id in args.ids:
        with tempfile.TemporaryDirectory(prefix="first-step-") as cache:
            cold = run_child(env_id, Path(cache))
            warm = run_child(env_id, Path(cache))
        kernels[env_id] = cold["kernels"]
        compiled = sum(own for own, _, _ in cold["kernels"].values())
        rows.append(
            [
                env_id,
                f"{warm['import'][1]:.2f}",
                f"{cold['first'][0]:.1f} / {cold['first'][1]:.1f}",
                f"{warm['first'][0]:.2f} / {warm['first'][1]:.2f}",
                f"{cold['first'][1] / warm['first'][1]:.0f}",
                f"{compiled:.1f}",
                len(cold["kernels"]),
            ]
        )
    print_table(
        "1. First step (gym.make, reset, one step) in a fresh process, s",
        [
            "env id",
            "import CPU (warm)",
            "cold wall / CPU",
            "warm wall / CPU",
            "cold / warm CPU",
            "compile CPU",
            "kernels compiled",
        ],
        rows,
    )
    for env_id, timings in kernels.items():
        total = sum(own for own, _, _ in timings.values())
        ranked = sorted(timings.items(), key=lambda item: -item[1][0])[: args.top]
        print()
        print_table(
            f"2. {env_id}: the kernels' own compile time, cold (callees' compiles excluded)",
            ["kernel", "compiles", "own CPU s", "of which LLVM s", "share of compile"],
            [
                [name, n, f"{own:.2f}", f"{llvm:.2f}", f"{own / total:.0%}"]
                for name, (own, llvm, n) in ranked
            ],
        )
    print(machine_line())


if __name__ == "__main__":
    if sys.argv[1:2] == [CHILD]:  # before main's imports: the child times its own
        child(sys.argv[2])
    else:
        main()
