"""``elastic-gym precompile``: compile the simulation's kernels into numba's cache."""

from __future__ import annotations

import argparse
import time


def add_parser(subcommands: argparse._SubParsersAction) -> None:
    parser = subcommands.add_parser(
        "precompile",
        help="compile the simulation's kernels ahead of their first use",
        description="Compile every numba kernel of the package into its cache, so that no "
        "later process waits for the compiler (a first env step after an install "
        "otherwise takes about half a minute to a minute). Run it once after an install, "
        "e.g. in a container image's build. Each step prints its time and how many "
        "kernels it compiled (0: all loaded from the cache).",
    )
    parser.add_argument(
        "--jobs",
        type=int,
        choices=(1, 2),
        default=2,
        help="processes compiling at once (default 2: half the wall time on 2 cores)",
    )
    parser.set_defaults(handler=run_precompile)


def run_precompile(args: argparse.Namespace) -> int:
    from elastic_gym.precompile import precompile

    print(f"compiling the kernels into numba's cache ({args.jobs} process{_s(args.jobs)}) ...")
    started = time.monotonic()
    times = precompile(jobs=args.jobs, progress=print)
    compiled = sum(count for _, _, count in times)
    print(
        f"{compiled} kernels compiled in {time.monotonic() - started:.1f} s "
        f"({len(times)} steps, {args.jobs} process{_s(args.jobs)})"
    )
    return 0


def _s(count: int) -> str:
    return "es" if count > 1 else ""
