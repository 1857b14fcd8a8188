"""Stress test of elastic-gym: many random-action episodes on every env id and wrapper.

    python studies/stress.py       # 100 episodes of <= 500 steps per (id, wrapper): 3000
    python studies/stress.py --episodes 20 --steps 500 --ids elastic_gym/KR15Elastic-v0
    python studies/stress.py --wrappers raw deluca ekf --workers 2

Wrappers: ``raw`` (the sensor observation), ``true-state`` (``TrueStateWrapper``) and
``ObserverWrapper`` with every observer name that applies to the arm. Each episode draws
a task (tracking, regulation, excitation), a torque scale (1 %, 10 %, 100 % or 200 % of
the limits: beyond 100 % the env clips) and an action style (white noise, or random
levels held 10-300 ms), and runs to truncation (``--steps``) or termination.

Counted: crashes (an exception from ``reset``/``step``; target 0), steps of episodes
that had not terminated with a non-finite number anywhere in the observation, reward
or ``info`` (target 0), and terminations by reason (the env's documented way to end
an episode whose physics broke, e.g. a joint limit crossed; a diverging observer ends
its episode through ``ObserverWrapper`` with "non-finite state estimate"). Exit code 1
if a crash or a non-finite value occurred.
"""

from __future__ import annotations

import argparse
import collections
import traceback
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
from rich import box
from rich.console import Console
from rich.table import Table

import elastic_gym
from elastic_gym.observers import ObserverWrapper, TrueStateWrapper
from elastic_gym.observers.registry import OBSERVERS, applicable_observers
from elastic_gym.robots.catalog import get_robot
from elastic_gym.runtime.parallel import run_jobs

TASKS = ("tracking", "regulation", "excitation")
TORQUE_SCALES = (0.01, 0.1, 1.0, 2.0)
HOLD_STEPS = (10, 300)  # range of the hold time of the "levels" action style (control periods)
WRAPPER_NAMES = ("raw", "true-state")  # + the applicable observer names ("true" = true-state)


def wrappers_for(env_id: str) -> list[str]:
    """``raw``, ``true-state`` and every observer applicable to the env's arm."""
    elastic = get_robot(gym.spec(env_id).kwargs["robot"]).elastic
    return [*WRAPPER_NAMES, *(n for n in applicable_observers(elastic) if n != "true")]


def make_env(env_id: str, wrapper: str, task: str, steps: int) -> gym.Env:
    env = gym.make(env_id, task=task, max_episode_steps=steps)
    if wrapper == "raw":
        return env
    if wrapper == "true-state":
        return TrueStateWrapper(env)
    return ObserverWrapper(env, wrapper)


def non_finite(value) -> bool:
    """Whether a (nested) observation/info value holds a NaN or an infinity.

    ``observer_diagnostics`` is left out: a condition number is legitimately infinite
    at an exactly singular accelerometer map.
    """
    if isinstance(value, dict):
        return any(non_finite(v) for k, v in value.items() if k != "observer_diagnostics")
    if isinstance(value, (bool, str)) or value is None:
        return False
    arr = np.asarray(value)
    return arr.dtype.kind in "fc" and not np.all(np.isfinite(arr))


@dataclass(frozen=True)
class Job:
    env_id: str
    wrapper: str
    task: str
    seeds: tuple[int, ...]
    steps: int


@dataclass
class Tally:
    """Outcome counts of a job (or of several, see `add`)."""

    episodes: int = 0
    steps: int = 0
    truncated: int = 0
    crashes: int = 0
    non_finite_steps: int = 0
    terminations: collections.Counter = field(default_factory=collections.Counter)
    first_errors: list[str] = field(default_factory=list)

    def add(self, other: Tally) -> None:
        for name in ("episodes", "steps", "truncated", "crashes", "non_finite_steps"):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.terminations.update(other.terminations)
        self.first_errors += other.first_errors[: max(0, 3 - len(self.first_errors))]


def random_actions(rng: np.random.Generator, limit: np.ndarray, steps: int) -> np.ndarray:
    """(steps, N) torques: white noise or held random levels at a random scale."""
    scale = rng.choice(TORQUE_SCALES) * limit
    if rng.random() < 0.5:
        return scale * rng.uniform(-1.0, 1.0, (steps, len(limit)))
    levels = []
    while len(levels) < steps:
        hold = int(rng.integers(*HOLD_STEPS))
        levels += [scale * rng.uniform(-1.0, 1.0, len(limit))] * hold
    return np.array(levels[:steps])


def run_episode(env: gym.Env, seed: int, steps: int, tally: Tally) -> None:
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    tally.non_finite_steps += non_finite(obs) or non_finite(info)
    for action in random_actions(rng, env.unwrapped.torque_limit, steps):
        obs, reward, terminated, truncated, info = env.step(action)
        tally.steps += 1
        if terminated:
            tally.terminations[info.get("termination_reason") or "terminated"] += 1
            return
        tally.non_finite_steps += non_finite(obs) or non_finite(reward) or non_finite(info)
        if truncated:
            tally.truncated += 1
            return


def run_job(job: Job) -> Tally:
    """The episodes of one (id, wrapper, task); a crash is counted and the env rebuilt."""
    tally = Tally()
    env = None
    for seed in job.seeds:
        tally.episodes += 1
        try:
            env = env or make_env(job.env_id, job.wrapper, job.task, job.steps)
            run_episode(env, seed, job.steps, tally)
        except Exception as exc:  # a crash is what this script looks for: count, go on
            tally.crashes += 1
            tally.first_errors.append(
                f"{job.env_id} {job.wrapper} {job.task} seed {seed}: "
                + "".join(traceback.format_exception_only(exc)).strip()
            )
            if env is not None:
                env.close()
            env = None
    if env is not None:
        env.close()
    return tally


def plan(
    env_ids: list[str], wrappers: list[str] | None, episodes: int, steps: int, chunk: int, seed: int
) -> list[Job]:
    """Jobs of ``chunk`` episodes; every (id, wrapper) gets ``episodes`` episodes spread
    over the tasks, each with its own seed."""
    jobs = []
    for env_id in env_ids:
        names = wrappers_for(env_id)
        for wrapper in names if wrappers is None else [w for w in wrappers if w in names]:
            for i, task in enumerate(TASKS):
                count = episodes // len(TASKS) + (i < episodes % len(TASKS))
                seeds = [seed + 1000 * i + k for k in range(count)]
                jobs += [
                    Job(env_id, wrapper, task, tuple(seeds[s : s + chunk]), steps)
                    for s in range(0, count, chunk)
                ]
    return jobs


def report(jobs: list[Job], tallies: list[Tally]) -> Tally:
    """Print the table per (id, wrapper) and the totals; return the totals."""
    groups: dict[tuple[str, str], Tally] = {}
    for job, tally in zip(jobs, tallies, strict=True):
        groups.setdefault((job.env_id, job.wrapper), Tally()).add(tally)
    total = Tally()
    rows = []
    for (env_id, wrapper), tally in groups.items():
        total.add(tally)
        reasons = ", ".join(f"{r} {c}" for r, c in tally.terminations.most_common()) or "-"
        rows.append(
            (
                env_id.split("/")[-1],
                wrapper,
                tally.episodes,
                tally.steps,
                tally.truncated,
                reasons,
                tally.crashes,
                tally.non_finite_steps,
            )
        )
    rows.append(
        (
            "total",
            "",
            total.episodes,
            total.steps,
            total.truncated,
            sum(total.terminations.values()),
            total.crashes,
            total.non_finite_steps,
        )
    )
    headers = (
        "env",
        "wrapper",
        "episodes",
        "steps",
        "truncated",
        "terminated (reason)",
        "crashes",
        "non-finite steps",
    )
    table = Table(
        *headers,
        title="stress: random-action episodes (targets: 0 crashes, 0 non-finite)",
        box=box.MARKDOWN,
        title_justify="left",
    )
    for row in rows:
        table.add_row(*(str(cell) for cell in row))
    Console(width=160).print(table)
    for line in total.first_errors:
        print("crash:", line)
    return total


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--episodes", type=int, default=100, help="episodes per (env id, wrapper) (default 100)"
    )
    parser.add_argument(
        "--steps", type=int, default=500, help="episode length: max_episode_steps (default 500)"
    )
    parser.add_argument(
        "--ids", nargs="+", default=list(elastic_gym.ENV_IDS), help="env ids (default: all)"
    )
    parser.add_argument(
        "--wrappers",
        nargs="+",
        help="subset of: raw, true-state and observer names (default: all applicable to each id)",
    )
    parser.add_argument("--workers", type=int, help="worker processes (default: one per CPU)")
    parser.add_argument("--chunk", type=int, default=10, help="episodes per job (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    args = parser.parse_args(argv)
    for key in ("episodes", "steps", "chunk"):
        if getattr(args, key) < 1:
            parser.error(f"--{key} must be >= 1")
    unknown = set(args.ids) - set(elastic_gym.ENV_IDS)
    if unknown:
        parser.error(f"unknown env id(s) {sorted(unknown)}; valid: {list(elastic_gym.ENV_IDS)}")
    valid_wrappers = {*WRAPPER_NAMES, *OBSERVERS} - {"true"}
    unknown = set(args.wrappers or ()) - valid_wrappers
    if unknown:
        parser.error(f"unknown wrapper(s) {sorted(unknown)}; valid: {sorted(valid_wrappers)}")
    jobs = plan(args.ids, args.wrappers, args.episodes, args.steps, args.chunk, args.seed)
    if not jobs:
        parser.error("no (id, wrapper) combination selected")
    tallies = run_jobs(
        run_job,
        jobs,
        workers=args.workers,
        label=f"stress (jobs of {args.chunk} episodes)",
        describe=lambda job: f"{job.env_id} {job.wrapper} {job.task}",
    )
    total = report(jobs, tallies)
    return 1 if total.crashes or total.non_finite_steps else 0


if __name__ == "__main__":
    raise SystemExit(main())
