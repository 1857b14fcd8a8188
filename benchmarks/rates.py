"""Rates of the converged physics (`integrator="rk4"`), as ratios measured in one run.

    python benchmarks/rates.py                  # tables 1-3 (a few minutes on 2 cores)
    python benchmarks/rates.py --quick          # short blocks
    python benchmarks/rates.py --tables 4       # the benchmark entry and robustness preset

Needs the optional ``mujoco`` package for table 1's anchor (``pip install mujoco``).
CPU time of this process (single-threaded BLAS), best of interleaved blocks (``timing.py``),
so the machine's load enters the ratios little; table 4 reports CPU seconds and the wall
time they make on 2 cores.

1. The closed loop of the comparisons (vector env + vector De Luca observer + vector
   eq. (13) of De Luca et al. 2007, N = 64 TwoLinkElastic arms) per arm and control
   millisecond: the RK4 at the 1 ms control period / PyBullet's Euler at 1/16 ms (target
   >= 8x faster), and / a bare MuJoCo step of the same arm (``mujoco_anchor.py``: one arm
   in a model and 64 arms in one model, 1 ms, its Euler and its RK4; target <= 3x);
2. the single env step (``gym.make``, RK4, with the checker and order wrappers it adds:
   what a user pays) / a bare one-arm step of the same integrator (`ArmIntegrator.step`;
   target <= 3x), per env id, the same without the wrappers (``env.unwrapped``), and
   PyBullet's env step at the robot's default physics step (what `gym.make` gives) / the
   RK4's;
3. PPO end to end (the ppo.yaml recipe of TwoLinkElastic: 32 arms in one world, decimation
   10, one process): control periods per CPU second on the RK4 / on PyBullet at the robot's
   0.5 ms (the default before the RK4; target >= 1x);
4. one benchmark entry (eq. (13) + De Luca on elastic-gym-v2, both robots, 10 seeds) and the
   robustness preset (both seeds), run in this process: CPU seconds, and CPU / 2 = their wall
   time on 2 cores (targets <= 20 s and <= 2 min).
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np
from batched import AT_REST, ClosedLoop
from mujoco_anchor import BareIntegrator, BareMujoco, MujocoArms, gravity_torques, initial_state
from timing import (
    ensure_single_thread_blas,
    interleaved_best,
    machine_line,
    print_table,
    seconds_per_call,
)

import elastic_gym
from elastic_gym.model import RobotModel
from elastic_gym.robots.catalog import get_robot

TWO_LINK = "elastic_gym/TwoLinkElastic-v0"
N_ARMS = 64
BULLET_FINE = 1.0 / 16000.0  # s: PyBullet's step of the comparisons before the RK4
ELASTIC = {
    "elastic_gym/TwoLinkElastic-v0": "two_link_elastic",
    "elastic_gym/KR15Elastic-v0": "kr15_elastic",
    "elastic_gym/IiwaElastic-v0": "iiwa_elastic",
}


def closed_loop_table(block: int, repeats: int) -> None:
    """Table 1."""
    model = RobotModel(get_robot("two_link_elastic"))
    loops = {
        "closed loop, RK4 at 1 ms": ClosedLoop(TWO_LINK, N_ARMS, "deluca", integrator="rk4"),
        "closed loop, PyBullet at 1/16 ms": ClosedLoop(
            TWO_LINK, N_ARMS, "deluca", integrator="pybullet", physics_dt=BULLET_FINE
        ),
    }
    steps = max(5, block // N_ARMS)
    x0 = initial_state(model, N_ARMS)
    torques = gravity_torques(model, x0, steps)
    bare = {}  # name -> (step, its arguments, arms it steps)
    one = initial_state(model, 1)
    one_torques = gravity_torques(model, one, block)
    for integrator in ("Euler", "RK4"):
        for n_arms, x, tau in ((N_ARMS, x0, torques), (1, one, one_torques)):
            arms = MujocoArms(model, n_arms, integrator)
            arms.set_state(x)
            bare[f"bare MuJoCo {integrator}, {n_arms} arm(s) in a model"] = (
                BareMujoco(arms).step,
                [(np.ascontiguousarray(t.ravel()),) for t in tau],
                n_arms,
            )
    bare["bare elastic_gym RK4, 64 arms"] = (
        BareIntegrator(model, x0).step,
        [(np.ascontiguousarray(tau),) for tau in torques],
        N_ARMS,
    )
    blocks = {
        name: (lambda f=loop.step: seconds_per_call(f, [()] * steps) / N_ARMS)
        for name, loop in loops.items()
    }
    blocks |= {
        name: (lambda f=f, a=a, n=n: seconds_per_call(f, a) / n) for name, (f, a, n) in bare.items()
    }
    cost = interleaved_best(blocks, repeats)
    for loop in loops.values():
        loop.close()
    rk4 = cost["closed loop, RK4 at 1 ms"]
    print_table(
        f"1. Closed loop (env + De Luca + eq. (13)), TwoLinkElastic, N = {N_ARMS}, per arm "
        "and control ms (CPU time)",
        ["loop", "us", "/ closed loop RK4", "closed loop RK4 / it"],
        [[name, f"{c * 1e6:.3g}", f"{c / rk4:.2f}", f"{rk4 / c:.2f}"] for name, c in cost.items()],
    )
    mujoco = {k: v for k, v in cost.items() if k.startswith("bare MuJoCo")}
    print(
        f"PyBullet 1/16 ms / RK4: {cost['closed loop, PyBullet at 1/16 ms'] / rk4:.1f}x "
        "(target >= 8); RK4 closed loop / "
        + ", / ".join(f"{k[5:]}: {rk4 / v:.2f}x" for k, v in mujoco.items())
        + " (target <= 3)\n"
    )


def single_env_table(block: int, repeats: int) -> None:
    """Table 2 (with PyBullet's env step at the robot's default physics step beside it)."""
    rows = []
    for env_id, robot in ELASTIC.items():
        envs = {
            "rk4": gym.make(env_id, integrator="rk4", **AT_REST),
            "pybullet": gym.make(env_id, integrator="pybullet", **AT_REST),
        }
        for env in envs.values():
            env.reset(seed=0)
        zero = np.zeros(envs["rk4"].action_space.shape)
        model = RobotModel(get_robot(robot))
        x0 = initial_state(model, 1)
        bare = BareIntegrator(model, x0)
        static = [(model.K * (x0[:, : model.n] - x0[:, model.n : 2 * model.n]),)] * block
        blocks = {
            name: (lambda env=env, zero=zero: seconds_per_call(env.step, [(zero,)] * block))
            for name, env in envs.items()
        }
        unwrapped = envs["rk4"].unwrapped  # without gym.make's checker and order wrappers
        blocks["rk4 unwrapped"] = lambda env=unwrapped, zero=zero: seconds_per_call(
            env.step, [(zero,)] * block
        )
        blocks["bare"] = lambda bare=bare, static=static: seconds_per_call(bare.step, static)
        cost = interleaved_best(blocks, repeats)
        for env in envs.values():
            env.close()
        rows.append(
            [
                env_id.split("/")[1],
                f"{cost['rk4'] * 1e6:.3g}",
                f"{cost['bare'] * 1e6:.3g}",
                f"{cost['rk4'] / cost['bare']:.2f}",
                f"{cost['rk4 unwrapped'] / cost['bare']:.2f}",
                f"{cost['pybullet'] * 1e6:.3g}",
                f"{cost['pybullet'] / cost['rk4']:.2f}",
            ]
        )
    print_table(
        "2. Single env step (gym.make, at rest, CPU time): the RK4 / a bare one-arm RK4 step; "
        "PyBullet's env at the robot's default physics step / the RK4's",
        [
            "env",
            "RK4 env us",
            "bare RK4 us",
            "ratio (target <= 3)",
            "unwrapped env / bare",
            "PyBullet env us",
            "/ RK4",
        ],
        rows,
    )
    print()


def ppo_table(policy_steps: int) -> None:
    """Table 3: PPO learning, control periods per CPU second, per physics."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from elastic_gym.policy import PolicySpec, build_policy_env
    from elastic_gym.training.config import resolve_settings
    from elastic_gym.training.sb3_vec_env import SB3VecEnv

    torch.set_num_threads(1)
    settings, algorithm = resolve_settings("ppo", TWO_LINK)
    physics = {
        "RK4 at 1 ms (the RL default)": {"integrator": "rk4"},
        "PyBullet at 0.5 ms (the default before)": {"integrator": "pybullet"},
    }
    rates = {}
    for label, kwargs in physics.items():
        spec = PolicySpec(
            env_id=TWO_LINK,
            env_kwargs={**settings.env_kwargs, **kwargs},
            state="true",
            decimation=settings.decimation,
            action=settings.action,
            observation=settings.observation,
        )
        envs = build_policy_env(spec, spec.make_env(settings.n_envs // settings.batches))
        venv = VecNormalize(SB3VecEnv(envs))
        model = PPO("MlpPolicy", venv, seed=0, device="cpu", **algorithm)
        model.learn(algorithm["n_steps"] * venv.num_envs)  # warm-up: the first rollout
        start, done = time.process_time(), model.num_timesteps
        model.learn(policy_steps, reset_num_timesteps=False)
        periods = (model.num_timesteps - done) * settings.decimation
        rates[label] = periods / (time.process_time() - start)
        venv.close()
    base = rates["PyBullet at 0.5 ms (the default before)"]
    print_table(
        f"3. PPO end to end (ppo.yaml, TwoLinkElastic, {settings.n_envs // settings.batches} "
        "arms, one process): control periods per CPU second",
        ["physics", "periods / s", "/ PyBullet 0.5 ms (target >= 1)"],
        [[k, f"{v:.0f}", f"{v / base:.2f}"] for k, v in rates.items()],
    )
    print()


def suite_table() -> None:
    """Table 4: CPU seconds of one benchmark entry and of the robustness preset."""
    from elastic_gym.benchmark import load_suite
    from elastic_gym.benchmark.suite import suite_scenario
    from elastic_gym.evaluation import load_preset, plan_runs
    from elastic_gym.evaluation.episodes import run_group
    from elastic_gym.evaluation.groups import plan_groups
    from elastic_gym.evaluation.scenario import ControllerEntry, SourceEntry

    entry = (ControllerEntry(name="feedforward-state-feedback"), SourceEntry(name="deluca"))
    scenarios = {
        "benchmark entry eq. (13) + De Luca, elastic-gym-v2": suite_scenario(
            load_suite("elastic-gym-v2"), *entry
        ),
        "robustness preset (2 seeds)": load_preset("robustness"),
    }
    rows = []
    for label, scenario in scenarios.items():
        runs, _ = plan_runs(scenario)
        start = time.process_time()
        for group in plan_groups(runs, workers=2):
            run_group(group)
        cpu = time.process_time() - start
        rows.append([label, str(len(runs)), f"{cpu:.1f}", f"{cpu / 2:.1f}"])
    print_table(
        "4. CPU seconds in this process, and their wall time on 2 cores (targets 20 s, 2 min)",
        ["run", "episodes", "CPU s", "CPU s / 2"],
        rows,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--tables", type=int, nargs="+", default=[1, 2, 3])
    args = parser.parse_args()
    ensure_single_thread_blas()
    print(f"elastic-gym {elastic_gym.__version__}; {machine_line()}\n")
    block, repeats, policy_steps = (640, 3, 4096) if args.quick else (6400, 7, 16384)
    if 1 in args.tables:
        closed_loop_table(block, repeats)
    if 2 in args.tables:
        single_env_table(block // 4, repeats)
    if 3 in args.tables:
        ppo_table(policy_steps)
    if 4 in args.tables:
        suite_table()
    print(machine_line())


if __name__ == "__main__":
    main()
