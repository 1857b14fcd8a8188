"""Benchmarks of elastic-gym: cost ratios measured in one run on this machine.

    python benchmarks/bench.py            # all tables (about a minute on 2 cores)
    python benchmarks/bench.py --quick    # the same tables with short blocks (~15 s)
    python benchmarks/bench.py --profile  # + where the time of the closed loop goes (cProfile)

Tables (BLAS single-threaded: "one core"; see ``timing.py`` for the method):

1. env step (sensors, task, reward, info, through ``gym.make``'s wrappers; ``excitation``
   task, see ``ENV_KWARGS``) / a bare PyBullet loop doing the same physics work
   (`BarePyBullet`), per env id (target <= 2.5x);
2. observer update / env step, for every observer that applies to each arm
   (N = 2, 3, 7; target for De Luca <= 0.3x at N = 7);
3. closed loop (env + observer + eq. (13) controller of De Luca et al.) simulated time /
   wall time at 1 kHz, with the split of a step (target >= 50x real time for the 7-DOF
   arm, higher for 2 links); rigid arms use the Cristofaro-De Luca reduced-order observer;
4. vectorized throughput: ``gymnasium.make_vec`` and SB3 ``SubprocVecEnv`` steps/s with
   1 and 2 workers, relative to one env stepped in this process;
5. batched arms (``batched.py``): the vector env of N arms in one PyBullet world / a bare
   N-arm PyBullet loop per arm-step (target <= 2x at N = 64), its throughput / one env
   (target >= 3x), the batched closed loop with the vector De Luca observer, and PPO
   policy steps/s on a batch vs ``SubprocVecEnv``;
6. the batched closed loop of the comparisons (``batched.py``): vector env + vector De
   Luca (or batched EKF) + vector eq. (13), 64 arms, per arm-step, at the env's physics
   step and at 1/16 ms, / the bare 64-arm PyBullet loop of the same world and substeps
   (target <= 2.5x), the EKF loop / the De Luca loop (target <= 3x), and the loop with
   eq. (13) identifying the load at the reset / the De Luca loop;
7. ``compare`` of one grid (``batched_compare.py``) with one arm per world
   (``--batch-size 1``) / batched, CPU time of the whole execution, at the env's 0.5 ms
   physics step and at the comparisons' 1/16 ms (targets >= 8x and >= 2.5x);
8. the distillation's training stack (``batched.py``): policy step of 32 arms with the
   plant teacher's labels / without them.

``--tables 1 5`` runs only some tables.
"""

from __future__ import annotations

import argparse
import cProfile
import functools
import math
import os
import pstats
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import batched
import batched_compare
import gymnasium as gym
import numpy as np
import pybullet as p
from timing import (
    ensure_single_thread_blas,
    interleaved_best,
    machine_line,
    print_table,
    seconds_per_call,
)

import elastic_gym
from elastic_gym.controllers.base import public_info
from elastic_gym.controllers.registry import make_controller
from elastic_gym.envs.simulator import ArmSimulator
from elastic_gym.observers import ObserverWrapper
from elastic_gym.observers.registry import applicable_observers, make_observer
from elastic_gym.policy.wrappers import ActionRepeat

CONTROLLER = "feedforward-state-feedback"  # eq. (13)
LOOP_OBSERVER = {"elastic": "deluca", "rigid": "reduced-order"}
TARGET_ENV_RATIO = 2.5
TARGET_DELUCA_RATIO = 0.3
TARGET_REALTIME = 50.0
# Tables 1, 2, 4: the env applies the gravity torque g(q) by itself and the action is zero:
# the arm stays at rest for ever (the cost of a step does not depend on the motion). Moving
# open loop, the light iiwa wrist reaches a joint limit within a second even at 0.5 % of
# the torque limits.
ENV_KWARGS = {"task": "excitation", "task_options": {"amplitude": 0.0}, "episode_time": None}
DECIMATION = 10  # action repeat of the RL-style rows of table 4
VEC_BLOCKS = 3  # table 4 keeps the best of this many blocks


@dataclass(frozen=True)
class Scale:
    """Block length (steps), number of interleaved repeats, vectorized steps."""

    block: int
    repeats: int
    vec_steps: int
    ppo_steps: int


FULL = Scale(block=500, repeats=7, vec_steps=3000, ppo_steps=8192)
QUICK = Scale(block=150, repeats=3, vec_steps=500, ppo_steps=2048)
BATCH_SIZES = (1, 8, 64, 256)
BATCH_ARMS = 64  # throughput, closed loop and PPO rows
TEACHER_ARMS = 32  # the distilled recipe's arms per batch


def make_env(env_id: str, **kwargs) -> gym.Env:
    """An env whose episodes never end by time (benchmark blocks are long)."""
    return gym.make(env_id, **{"episode_time": None, **kwargs})


def kind(env: gym.Env) -> str:
    return env.unwrapped.robot.kind


def checked_step(env: gym.Env, action: np.ndarray) -> tuple:
    """``env.step`` that refuses to let a benchmark episode end unnoticed."""
    result = env.step(action)
    if result[2] or result[3]:
        raise RuntimeError(
            f"{env.spec.id} ended during the benchmark: {result[4].get('termination_reason')}"
        )
    return result


class BarePyBullet:
    """The env's physics work in a bare PyBullet loop.

    The same URDF loaded the same way (an `ArmSimulator`: limits removed, fixed
    base, inertia from the file, damping zeroed, default motors disabled), started in
    the env's state, with the same number of physics substeps per control period; each
    substep is setJointMotorControlArray(TORQUE) + stepSimulation + getJointStates.
    """

    def __init__(self, env: gym.Env) -> None:
        u = env.unwrapped
        self.sim = ArmSimulator(u.robot, u.plant_model, u.physics_dt)
        self.sim.reset_state(np.array([0]), u.sim.q, u.sim.dq, u.sim.theta, u.sim.dtheta)
        self.n_substeps = u.n_substeps

    def step(self, torque: np.ndarray) -> None:
        sim = self.sim
        body, joints, client = sim.bodies[0], sim.joint_indices, sim.client
        forces = torque.tolist()  # PyBullet converts a list faster than an array
        for _ in range(self.n_substeps):
            p.setJointMotorControlArray(
                body, joints, p.TORQUE_CONTROL, forces=forces, physicsClientId=client
            )
            p.stepSimulation(physicsClientId=client)
            p.getJointStates(body, joints, physicsClientId=client)

    def close(self) -> None:
        self.sim.close()


def blocks_of(actions: np.ndarray, block: int):
    """Consecutive blocks of ``block`` actions, as argument tuples."""
    for start in range(0, len(actions), block):
        yield [(a,) for a in actions[start : start + block]]


# ---------------------------------------------------------------------------- table 1
def env_step_costs(env_id: str, scale: Scale) -> dict[str, float]:
    """Best seconds per control period of the env and of the bare PyBullet loop."""
    env = make_env(env_id, **ENV_KWARGS)
    _, info = env.reset(seed=0)
    bare = BarePyBullet(env)
    steps = scale.block * scale.repeats
    env_blocks = blocks_of(np.zeros((steps, env.unwrapped.n_joints)), scale.block)
    bare_blocks = blocks_of(np.tile(info["torque"], (steps, 1)), scale.block)  # at rest too
    step = functools.partial(checked_step, env)
    costs = interleaved_best(
        {
            "env": lambda: seconds_per_call(step, next(env_blocks)),
            "bare": lambda: seconds_per_call(bare.step, next(bare_blocks)),
        },
        scale.repeats,
    )
    env.close()
    bare.close()
    return costs


# ---------------------------------------------------------------------------- table 2
def record_measurements(env_id: str, steps: int) -> tuple[dict, list[tuple], float]:
    """(first measurement, [(measurement, applied torque, dt)], dt) of a probe episode.

    A measurement is the sensor observation plus the privileged items some observers
    declare (true q'', true state), as `ObserverWrapper` would pass them.
    """
    env = make_env(env_id, **ENV_KWARGS)
    obs, info = env.reset(seed=0)

    def measurement(obs: dict, info: dict) -> dict:
        return {
            **obs,
            "link_acceleration": info["true_state"]["ddq"],
            "true_state": info["true_state"],
        }

    first = measurement(obs, info)
    dt = env.unwrapped.control_dt
    updates = []
    for _ in range(steps):
        obs, _, _, _, info = checked_step(env, np.zeros(env.unwrapped.n_joints))
        updates.append((measurement(obs, info), info["torque"], dt))
    env.close()
    return first, updates, dt


def observer_update_costs(env_id: str, scale: Scale) -> tuple[int, dict[str, float]]:
    """(N, best seconds per ``update`` of every observer applicable to the arm)."""
    first, updates, dt = record_measurements(env_id, scale.block)
    env = make_env(env_id)
    n = env.unwrapped.n_joints
    observers = {
        name: make_observer(name, env.unwrapped.model, dt)
        for name in applicable_observers(kind(env) == "elastic")
    }
    env.close()

    def block(observer) -> float:
        observer.reset(first)
        return seconds_per_call(observer.update, updates)

    return n, interleaved_best(
        {name: functools.partial(block, obs) for name, obs in observers.items()}, scale.repeats
    )


# ---------------------------------------------------------------------------- table 3
class ClosedLoop:
    """Env + observer wrapper + eq. (13) controller; records the controller's share."""

    def __init__(self, env_id: str, block: int) -> None:
        env = make_env(env_id)
        self.observer = LOOP_OBSERVER[kind(env)]
        self.env = ObserverWrapper(env, self.observer)
        u = env.unwrapped
        self.controller = make_controller(CONTROLLER, u.model, u.control_dt)
        self.block_steps = block
        self.obs, info = self.env.reset(seed=0)
        self.info = public_info(info)
        self.controller.reset(self.obs, self.info)
        self.best = math.inf
        self.best_controller = math.nan

    def block(self) -> float:
        """Seconds per closed-loop step over one block (controller time kept aside)."""
        controller_time = 0.0
        start = time.process_time()
        for _ in range(self.block_steps):
            tick = time.process_time()
            action = self.controller(self.obs, self.info)
            controller_time += time.process_time() - tick
            self.obs, _, _, _, info = checked_step(self.env, action)
            self.info = public_info(info)
        total = (time.process_time() - start) / self.block_steps
        if total < self.best:
            self.best, self.best_controller = total, controller_time / self.block_steps
        return total

    def close(self) -> None:
        self.env.close()


# ---------------------------------------------------------------------------- table 4
def _time_vector_env(
    vec, n_envs: int, n_joints: int, steps: int, gymnasium_api: bool, repeat: int
) -> float:
    """Env steps per second (all workers together, best of ``VEC_BLOCKS`` blocks) of a
    vectorized env whose every ``step`` runs ``repeat`` env steps per worker."""
    actions = np.zeros((n_envs, n_joints))
    if gymnasium_api:
        vec.reset(seed=0)
    else:
        vec.seed(0)
        vec.reset()
    for _ in range(20):  # warm-up: workers started, first-step checks done
        vec.step(actions)
    block = max(1, steps // VEC_BLOCKS)
    best = interleaved_best(
        {"vec": lambda: seconds_per_call(vec.step, [(actions,)] * block, clock=time.perf_counter)},
        VEC_BLOCKS,
    )["vec"]
    vec.close()
    return n_envs * repeat / best


def repeated_env(env_id: str, repeat: int) -> gym.Env:
    """Env whose step holds the action for ``repeat`` control periods (RL decimation)."""
    return ActionRepeat(gym.make(env_id, **ENV_KWARGS), repeat)


def vector_throughput(env_id: str, steps: int) -> list[tuple[str, int, int, float]]:
    """(method, workers, action repeat, env steps/s) of one in-process env and of the
    vectorized envs (repeat > 1: ``ActionRepeat`` inside the workers)."""
    from stable_baselines3.common.vec_env import SubprocVecEnv

    env = make_env(env_id, **ENV_KWARGS)
    n = env.unwrapped.n_joints
    env.reset(seed=0)
    zero = np.zeros(n)
    block = [(zero,)] * max(1, steps // VEC_BLOCKS)
    step = functools.partial(checked_step, env)
    single = (
        1.0
        / interleaved_best(
            {"env": lambda: seconds_per_call(step, block, clock=time.perf_counter)}, VEC_BLOCKS
        )["env"]
    )
    env.close()
    rows = [("one env, this process", 1, 1, single)]
    makers: list[tuple[str, int, int, Callable[[], object], bool]] = [
        (
            "gymnasium.make_vec sync",
            1,
            1,
            lambda: gym.make_vec(env_id, 1, vectorization_mode="sync", **ENV_KWARGS),
            True,
        ),
    ]
    for workers, repeat in ((1, 1), (2, 1), (2, DECIMATION)):
        factory = functools.partial(repeated_env, env_id, repeat)
        makers.append(
            (
                "gymnasium.make_vec async",
                workers,
                repeat,
                functools.partial(gym.vector.AsyncVectorEnv, [factory] * workers),
                True,
            )
        )
        makers.append(
            (
                "SB3 SubprocVecEnv",
                workers,
                repeat,
                functools.partial(SubprocVecEnv, [factory] * workers),
                False,
            )
        )
    for method, workers, repeat, make, gymnasium_api in makers:
        rows.append(
            (
                method,
                workers,
                repeat,
                _time_vector_env(make(), workers, n, steps // repeat, gymnasium_api, repeat),
            )
        )
    return rows


# ---------------------------------------------------------------------------- profile
def _label(key: tuple[str, int, str]) -> str:
    file, line, name = key
    if file == "~":
        return name
    return f"{Path(file).parent.name}/{Path(file).name}:{line}({name})"


def profile_closed_loop(env_id: str, steps: int, top: int) -> tuple[list[tuple], float]:
    """Top functions by own time of a closed-loop run under cProfile, and the profiled
    seconds per step (cProfile inflates Python-heavy code; compare with table 3)."""
    loop = ClosedLoop(env_id, steps)
    loop.block()  # warm-up
    profiler = cProfile.Profile()
    profiler.enable()
    per_step = loop.block()
    profiler.disable()
    loop.close()
    stats = pstats.Stats(profiler).stats
    total = sum(entry[2] for entry in stats.values())
    ranked = sorted(stats.items(), key=lambda item: item[1][2], reverse=True)[:top]
    rows = [
        (_label(key), f"{100 * tt / total:.1f}", f"{nc / steps:.0f}", f"{100 * ct / total:.1f}")
        for key, (_, nc, tt, ct, _) in ranked
    ]
    return rows, per_step


# ---------------------------------------------------------------------------- main
def fmt(value: float, digits: int = 3) -> str:
    return f"{value:.{digits}g}"


def table_env(env_ids: list[str], scale: Scale) -> dict[str, float]:
    env_costs = {}
    rows = []
    for env_id in env_ids:
        costs = env_step_costs(env_id, scale)
        env_costs[env_id] = costs["env"]
        ratio = costs["env"] / costs["bare"]
        rows.append(
            (
                env_id,
                fmt(1e6 * costs["env"]),
                fmt(1e6 * costs["bare"]),
                fmt(ratio),
                "yes" if ratio <= TARGET_ENV_RATIO else "no",
            )
        )
    print_table(
        f"1. env step / bare PyBullet (target <= {TARGET_ENV_RATIO}x)",
        ("env id", "env step [us]", "bare PyBullet [us]", "ratio", "target met"),
        rows,
    )
    return env_costs


def table_observers(env_ids: list[str], scale: Scale, env_costs: dict[str, float]) -> None:
    rows = []
    for env_id in env_ids:
        n, costs = observer_update_costs(env_id, scale)
        for name, cost in costs.items():
            ratio = cost / env_costs[env_id]
            target = (
                ("yes" if ratio <= TARGET_DELUCA_RATIO else "no")
                if name == "deluca" and "Iiwa" in env_id
                else ""
            )
            rows.append((env_id, n, name, fmt(1e6 * cost), fmt(ratio), target))
    print_table(
        f"2. observer update / env step (target De Luca <= {TARGET_DELUCA_RATIO}x at N = 7)",
        ("env id", "N", "observer", "update [us]", "ratio", "target met"),
        rows,
    )


def table_closed_loop(env_ids: list[str], scale: Scale, env_costs: dict[str, float]) -> None:
    rows = []
    for env_id in env_ids:
        loop = ClosedLoop(env_id, scale.block)
        interleaved_best({"loop": loop.block}, scale.repeats)
        loop.close()
        env_part = env_costs[env_id]
        observer_part = loop.best - loop.best_controller - env_part
        realtime = loop.env.unwrapped.control_dt / loop.best
        rows.append(
            (
                env_id,
                loop.observer,
                fmt(1e6 * loop.best),
                fmt(realtime),
                f"{100 * env_part / loop.best:.0f}",
                f"{100 * observer_part / loop.best:.0f}",
                f"{100 * loop.best_controller / loop.best:.0f}",
                "yes" if realtime >= TARGET_REALTIME else "no",
            )
        )
    print_table(
        f"3. closed loop at 1 kHz, simulated / wall time (target >= {TARGET_REALTIME:g}x;"
        " split of a step in %)",
        (
            "env id",
            "observer",
            "step [us]",
            "x real time",
            "env (table 1)",
            "observer+wrapper",
            "eq. (13) controller",
            "target met",
        ),
        rows,
    )


def table_vector(vec_id: str, scale: Scale) -> None:
    rows = vector_throughput(vec_id, scale.vec_steps)
    single = rows[0][3]
    print_table(
        f"4. vectorized throughput, {vec_id}",
        ("method", "workers", "action repeat", "env steps/s", "vs one env"),
        [(m, w, r, f"{s:.0f}", fmt(s / single)) for m, w, r, s in rows],
    )


def table_batched(env_ids: list[str], vec_id: str, scale: Scale) -> None:
    rows = []
    for env_id in env_ids:
        for n_arms, batch_us, bare_us, ratio in batched.batch_costs(
            env_id, BATCH_SIZES, scale.block * 4, scale.repeats
        ):
            target = (
                ("yes" if ratio <= batched.TARGET_BATCH_RATIO else "no")
                if (n_arms == BATCH_ARMS and env_id == vec_id)
                else ""
            )
            rows.append((env_id, n_arms, fmt(batch_us), fmt(bare_us), fmt(ratio), target))
    print_table(
        f"5a. batched env / bare N-arm PyBullet loop, per arm-step (target <= "
        f"{batched.TARGET_BATCH_RATIO:g}x at N = {BATCH_ARMS}, {vec_id})",
        ("env id", "arms N", "batched env [us]", "bare PyBullet [us]", "ratio", "target met"),
        rows,
    )
    costs = batched.throughput_and_loop(vec_id, BATCH_ARMS, scale.block, scale.repeats)
    gain = costs["single"] / costs["batch"]
    print_table(
        f"5b. {vec_id}, {BATCH_ARMS} arms in one world vs one env, per arm-step",
        ("loop", "one env [us]", f"batch of {BATCH_ARMS} [us]", "speed-up", "target met"),
        [
            (
                "env step",
                fmt(1e6 * costs["single"]),
                fmt(1e6 * costs["batch"]),
                fmt(gain),
                "yes" if gain >= batched.TARGET_THROUGHPUT else "no",
            ),
            (
                "env + De Luca observer",
                fmt(1e6 * costs["single+deluca"]),
                fmt(1e6 * costs["batch+deluca"]),
                fmt(costs["single+deluca"] / costs["batch+deluca"]),
                "",
            ),
        ],
    )
    workers = os.cpu_count() or 1
    rates = batched.ppo_policy_steps_per_second(vec_id, BATCH_ARMS, workers, scale.ppo_steps)
    first = next(iter(rates.values()))
    print_table(
        f"5c. PPO end to end, {vec_id} (true state, action repeat "
        f"{batched.PPO_DECIMATION}, rollout {batched.PPO_ROLLOUT} policy steps)",
        ("env", "policy steps/s", "vs batched"),
        [(label, f"{rate:.0f}", fmt(rate / first)) for label, rate in rates.items()],
    )


def table_batched_loop(vec_id: str, scale: Scale) -> None:
    rows = []
    for physics_dt in (None, batched.FINE_PHYSICS_DT):
        costs = batched.closed_loop_costs(
            vec_id, BATCH_ARMS, physics_dt, scale.block * 4, scale.repeats
        )
        loop_ratio = costs["deluca"] / costs["bare"]
        ekf_ratio = costs["ekf"] / costs["deluca"]
        rows.append(
            (
                f"{costs['substeps']}",
                fmt(1e6 * costs["bare"]),
                fmt(1e6 * costs["deluca"]),
                fmt(loop_ratio),
                fmt(1e6 * costs["ekf"]),
                fmt(ekf_ratio),
                fmt(costs["load-id"] / costs["deluca"]),
                f"{'yes' if loop_ratio <= batched.TARGET_LOOP_RATIO else 'no'} / "
                f"{'yes' if ekf_ratio <= batched.TARGET_EKF_RATIO else 'no'}",
            )
        )
    print_table(
        f"6. batched closed loop, {vec_id}, {BATCH_ARMS} arms: vector env + vector observer + "
        f"vector eq. (13), per arm-step (targets: De Luca loop <= "
        f"{batched.TARGET_LOOP_RATIO:g}x the bare loop, EKF loop <= "
        f"{batched.TARGET_EKF_RATIO:g}x the De Luca loop)",
        (
            "substeps per ms",
            "bare PyBullet [us]",
            "De Luca loop [us]",
            "vs bare",
            "EKF loop [us]",
            "vs De Luca loop",
            "load-id loop vs De Luca loop",
            "targets met",
        ),
        rows,
    )


def table_compare(scale: Scale) -> None:
    quick = scale is QUICK
    seeds = batched_compare.SEEDS // 2 if quick else batched_compare.SEEDS
    duration = batched_compare.DURATION / 2 if quick else batched_compare.DURATION
    rows = []
    for physics_dt, target in batched_compare.TARGET.items():
        costs = batched_compare.compare_costs(physics_dt, seeds, duration, 2 if quick else 3)
        ratio = costs["alone"] / costs["batched"]
        rows.append(
            (
                f"{1e3 * physics_dt:g}",
                costs["runs"],
                fmt(costs["alone"]),
                fmt(costs["batched"]),
                fmt(ratio),
                f"{target:g}x: {'yes' if ratio >= target else 'no'}",
            )
        )
    print_table(
        f"7. compare of one grid (TwoLinkElastic, eq. (13) and motor PD on the true state "
        f"and De Luca, {seeds} seeds, {duration:g} s per run): CPU time with one arm per "
        f"world / batched (worlds of {seeds} arms)",
        ("physics step [ms]", "runs", "batch size 1 [s]", "batched [s]", "speed-up", "target"),
        rows,
    )


def table_teacher(vec_id: str, scale: Scale) -> None:
    costs = batched.teacher_costs(vec_id, TEACHER_ARMS, scale.block // 5, scale.repeats)
    print_table(
        f"8. the distilled recipe's training stack, {vec_id}, {TEACHER_ARMS} arms: CPU "
        "time per policy step (10 control periods) with the plant teacher's labels",
        ("without teacher [ms]", "with teacher [ms]", "ratio"),
        [
            (
                fmt(1e3 * costs["without"]),
                fmt(1e3 * costs["teacher"]),
                fmt(costs["teacher"] / costs["without"]),
            )
        ],
    )


def run(env_ids: list[str], scale: Scale, vec_id: str, profile: bool, tables: set[int]) -> None:
    print(
        f"{machine_line()} (other processes slow the timings; "
        "each value is the best of interleaved blocks)\n"
    )
    env_costs = table_env(env_ids, scale) if tables & {1, 2, 3} else {}
    if 2 in tables:
        table_observers(env_ids, scale, env_costs)
    if 3 in tables:
        table_closed_loop(env_ids, scale, env_costs)
    if 4 in tables:
        table_vector(vec_id, scale)
    if 5 in tables:
        table_batched(env_ids, vec_id, scale)
    if 6 in tables:
        table_batched_loop(vec_id, scale)
    if 7 in tables:
        table_compare(scale)
    if 8 in tables:
        table_teacher(vec_id, scale)
    if profile:
        for env_id in env_ids:
            top, per_step = profile_closed_loop(env_id, scale.block, top=15)
            print_table(
                f"profile (cProfile), closed loop of table 3, {env_id}: "
                f"{fmt(1e6 * per_step)} us/step under the profiler",
                ("function", "own time %", "calls/step", "incl. callees %"),
                top,
            )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short blocks (about a minute)")
    parser.add_argument("--profile", action="store_true", help="cProfile the closed loop")
    parser.add_argument(
        "--ids", nargs="+", default=list(elastic_gym.ENV_IDS), help="env ids (default: all)"
    )
    parser.add_argument(
        "--vec-id",
        default="elastic_gym/TwoLinkElastic-v0",
        help="env id of the vectorized throughput and batch rows",
    )
    parser.add_argument(
        "--tables",
        nargs="+",
        type=int,
        default=[1, 2, 3, 4, 5, 6, 7, 8],
        choices=[1, 2, 3, 4, 5, 6, 7, 8],
        help="tables to run (default: all)",
    )
    args = parser.parse_args(argv)
    ensure_single_thread_blas()
    run(args.ids, QUICK if args.quick else FULL, args.vec_id, args.profile, set(args.tables))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
