"""Table 5 of ``bench.py``: batched arms (many arms in one PyBullet world).

* cost per arm-step of the vector env (``gym.make_vec(..., "vector_entry_point")``, the
  arms at rest under the excitation task's gravity torque) / a bare N-arm PyBullet loop
  of the same world (`BareBatch`), N = 1, 8, 64, 256 (target <= 2 at N = 64 for
  TwoLinkElastic);
* aggregate env steps/s of the batch / one single env stepped in the same process
  (target >= 3 at N = 64);
* the batched closed loop: vector env + vector De Luca observer, per arm-step, and the
  same loop of one arm (single env + De Luca);
* the batched closed loop of the comparisons: vector env + vector De Luca observer (or
  the batched EKF) + vector eq. (13), per arm-step at N = 64, at the env's physics step
  and at 1/16 ms, against the bare N-arm PyBullet loop of the same world and substeps
  (target <= 2.5), the EKF loop against the De Luca loop (target <= 3), and the De Luca
  loop with eq. (13) identifying the load at the reset against it;
* PPO policy steps/s end to end (rollouts + updates) on one batch of arms
  (`SB3VecEnv`) and on SB3's ``SubprocVecEnv``
  with one worker per core, with the same stack (true state, action repeat 10,
  flattened observation, actions in [-1, 1], VecNormalize) and the same rollout size;
* the training stack of the distilled recipe (``recurrentppo-distilled.yaml``: raw
  sensors, motor-offset action, action repeat 10) with the plant teacher's labels /
  without them, per policy step (table 8).
"""

from __future__ import annotations

import functools
import time

import gymnasium as gym
import numpy as np
import pybullet as p
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers import FlattenObservation, RescaleAction
from gymnasium.wrappers import vector as vector_wrappers
from timing import interleaved_best, seconds_per_call

from elastic_gym.controllers import public_info
from elastic_gym.controllers.vector import make_vector_controller
from elastic_gym.envs.simulator import ArmSimulator
from elastic_gym.observers import ObserverWrapper, TrueStateWrapper, vector
from elastic_gym.policy import PolicySpec, build_policy_env
from elastic_gym.policy import vector as training_vector
from elastic_gym.policy.wrappers import ActionRepeat
from elastic_gym.training.config import resolve_settings
from elastic_gym.training.teacher import PlantTeacher

AT_REST = {"task": "excitation", "task_options": {"amplitude": 0.0}, "episode_time": None}
TARGET_BATCH_RATIO = 2.0
TARGET_THROUGHPUT = 3.0
TARGET_LOOP_RATIO = 2.5  # vector env + De Luca + eq. (13) / bare PyBullet, N = 64
TARGET_EKF_RATIO = 3.0  # the same loop with the EKF / with De Luca
FINE_PHYSICS_DT = 1.0 / 16000.0  # the comparisons' physics step
LOOP_CONTROLLER = "feedforward-state-feedback"  # eq. (13)
PPO_DECIMATION = 10
PPO_ROLLOUT = 1024  # policy steps per rollout, whatever the number of envs
DISTILLED_RECIPE = "recurrentppo-distilled.yaml"


def vector_env(env_id: str, n_arms: int, **kwargs) -> gym.vector.VectorEnv:
    return gym.make_vec(
        env_id, num_envs=n_arms, vectorization_mode="vector_entry_point", **{**AT_REST, **kwargs}
    )


class BareBatch:
    """The vector env's physics work in a bare loop: the same N-arm world (an
    `ArmSimulator`), the same substeps; per substep one setJointMotorControlArray
    (TORQUE) per arm, one stepSimulation, one getJointStates per arm."""

    def __init__(self, envs: gym.vector.VectorEnv) -> None:
        batch = envs.unwrapped.batch
        self.sim = ArmSimulator(batch.robot, batch.plant_model, batch.physics_dt, batch.n_arms)
        self.sim.reset_state(
            np.arange(batch.n_arms), batch.sim.q, batch.sim.dq, batch.sim.theta, batch.sim.dtheta
        )
        self.n_substeps = batch.n_substeps
        self.forces = batch.torque.tolist()

    def step(self) -> None:
        sim = self.sim
        client, joints, bodies = sim.client, sim.joint_indices, sim.bodies
        for _ in range(self.n_substeps):
            for body, forces in zip(bodies, self.forces, strict=True):
                p.setJointMotorControlArray(
                    body, joints, p.TORQUE_CONTROL, forces=forces, physicsClientId=client
                )
            p.stepSimulation(physicsClientId=client)
            for body in bodies:
                p.getJointStates(body, joints, physicsClientId=client)

    def close(self) -> None:
        self.sim.close()


def _stepper(env, n_arms: int, n_joints: int, wrapped_single: bool = False):
    zero = np.zeros(n_joints) if wrapped_single else np.zeros((n_arms, n_joints))

    def step() -> None:
        env.step(zero)

    return step


def batch_costs(env_id: str, sizes: tuple[int, ...], block: int, repeats: int) -> list[tuple]:
    """(N, batched us/arm-step, bare us/arm-step, ratio) for each N."""
    rows = []
    for n_arms in sizes:
        envs = vector_env(env_id, n_arms)
        envs.reset(seed=0)
        bare = BareBatch(envs)
        steps = max(5, block // n_arms)
        step = _stepper(envs, n_arms, envs.unwrapped.n_joints)
        costs = interleaved_best(
            {
                "batch": lambda step=step, steps=steps: seconds_per_call(step, [()] * steps),
                "bare": lambda bare=bare, steps=steps: seconds_per_call(bare.step, [()] * steps),
            },
            repeats,
        )
        rows.append(
            (
                n_arms,
                1e6 * costs["batch"] / n_arms,
                1e6 * costs["bare"] / n_arms,
                costs["batch"] / costs["bare"],
            )
        )
        envs.close()
        bare.close()
    return rows


def throughput_and_loop(env_id: str, n_arms: int, block: int, repeats: int) -> dict[str, float]:
    """Seconds per arm-step: batch of ``n_arms`` and one single env (open loop), and the
    same two with the De Luca observer (closed-loop sensing path)."""
    single = gym.make(env_id, **AT_REST)
    single.reset(seed=0)
    envs = vector_env(env_id, n_arms)
    envs.reset(seed=0)
    single_loop = ObserverWrapper(gym.make(env_id, **AT_REST), "deluca")
    single_loop.reset(seed=0)
    batch_loop = vector.ObserverWrapper(vector_env(env_id, n_arms), "deluca")
    batch_loop.reset(seed=0)
    n = envs.unwrapped.n_joints
    batch_steps = max(5, block // n_arms)
    timed = {
        "single": (_stepper(single, 1, n, True), block, 1),
        "batch": (_stepper(envs, n_arms, n), batch_steps, n_arms),
        "single+deluca": (_stepper(single_loop, 1, n, True), block, 1),
        "batch+deluca": (_stepper(batch_loop, n_arms, n), batch_steps, n_arms),
    }
    costs = interleaved_best(
        {
            name: (lambda f=f, k=k, a=a: seconds_per_call(f, [()] * k) / a)
            for name, (f, k, a) in timed.items()
        },
        repeats,
    )
    for env in (single, envs, single_loop, batch_loop):
        env.close()
    return costs


class ClosedLoop:
    """N arms under a vector observer and vector eq. (13) (with ``controller_options``):
    one control period per step."""

    def __init__(
        self,
        env_id: str,
        n_arms: int,
        observer: str,
        controller_options: dict | None = None,
        **kwargs,
    ) -> None:
        self.envs = vector.ObserverWrapper(vector_env(env_id, n_arms, **kwargs), observer)
        batch = self.envs.unwrapped.batch
        self.controller = make_vector_controller(
            LOOP_CONTROLLER, batch.model, batch.control_dt, n_arms, **(controller_options or {})
        )
        obs, info = self.envs.reset(seed=0)
        self.controller.reset_arms(obs, public_info(info), np.arange(n_arms))
        self.obs, self.info = obs, public_info(info)

    def step(self) -> None:
        obs, _, _, _, info = self.envs.step(self.controller(self.obs, self.info))
        self.obs, self.info = obs, public_info(info)

    def close(self) -> None:
        self.envs.close()


def closed_loop_costs(
    env_id: str, n_arms: int, physics_dt: float | None, block: int, repeats: int
) -> dict[str, float]:
    """Seconds per arm-step of the batched closed loop with De Luca, with the EKF and with
    De Luca and eq. (13) identifying the load at the reset (``load-id``: n more INVDYN
    evaluations per call), and of the bare N-arm PyBullet loop of the same world and
    substeps."""
    kwargs = {} if physics_dt is None else {"physics_dt": physics_dt}
    loops = {name: ClosedLoop(env_id, n_arms, name, **kwargs) for name in ("deluca", "ekf")}
    identify = {"load_identification": "shared"}
    loops["load-id"] = ClosedLoop(env_id, n_arms, "deluca", identify, **kwargs)
    bare = BareBatch(loops["deluca"].envs)
    steps = max(5, block // n_arms)
    timed = {"bare": bare.step, **{name: loop.step for name, loop in loops.items()}}
    costs = interleaved_best(
        {
            name: (lambda f=f: seconds_per_call(f, [()] * steps) / n_arms)
            for name, f in timed.items()
        },
        repeats,
    )
    costs["substeps"] = loops["deluca"].envs.unwrapped.batch.n_substeps
    for loop in loops.values():
        loop.close()
    bare.close()
    return costs


def _batched_stack(env_id: str, n_arms: int):
    from elastic_gym.training.sb3_vec_env import SB3VecEnv

    envs = gym.make_vec(
        env_id,
        num_envs=n_arms,
        vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.DISABLED,
    )
    envs = training_vector.ActionRepeat(vector.TrueStateWrapper(envs), PPO_DECIMATION)
    envs = vector_wrappers.RescaleAction(vector_wrappers.FlattenObservation(envs), -1.0, 1.0)
    return SB3VecEnv(envs)


def _single_stack(env_id: str) -> gym.Env:
    env = ActionRepeat(TrueStateWrapper(gym.make(env_id)), PPO_DECIMATION)
    return RescaleAction(FlattenObservation(env), -1.0, 1.0)


def ppo_policy_steps_per_second(
    env_id: str, n_arms: int, workers: int, policy_steps: int
) -> dict[str, float]:
    """PPO policy steps/s on one batch of ``n_arms`` vs SubprocVecEnv with ``workers``."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import SubprocVecEnv, VecNormalize

    torch.set_num_threads(1)
    makers = {
        f"batched env, {n_arms} arms, 1 process": lambda: _batched_stack(env_id, n_arms),
        f"SubprocVecEnv, {workers} workers": lambda: SubprocVecEnv(
            [functools.partial(_single_stack, env_id)] * workers
        ),
    }
    rates = {}
    for label, make in makers.items():
        venv = VecNormalize(make())
        n_steps = max(8, PPO_ROLLOUT // venv.num_envs)
        model = PPO(
            "MlpPolicy", venv, n_steps=n_steps, batch_size=256, n_epochs=5, seed=0, device="cpu"
        )
        model.learn(n_steps * venv.num_envs)  # warm-up: workers up, first rollout
        start = time.perf_counter()
        model.learn(policy_steps, reset_num_timesteps=False)
        rates[label] = (model.num_timesteps - n_steps * venv.num_envs) / (
            time.perf_counter() - start
        )
        venv.close()
    return rates


def teacher_costs(env_id: str, n_arms: int, policy_steps: int, repeats: int) -> dict[str, float]:
    """CPU seconds per policy step of ``n_arms`` arms in the training stack of the
    distilled recipe (its env kwargs with the plant draws, action, observation and
    decimation), ``"teacher"`` with the plant teacher's labels and ``"without"`` them."""
    settings, _ = resolve_settings("recurrentppo", env_id, file=DISTILLED_RECIPE)

    spec = PolicySpec(
        env_id=env_id,
        state="sensors",
        env_kwargs=settings.env_kwargs,
        decimation=settings.decimation,
        action=settings.action,
        observation=settings.observation,
    )

    def stack(teacher: bool) -> gym.vector.VectorEnv:
        envs = build_policy_env(spec, spec.make_env(n_arms, autoreset_mode=AutoresetMode.NEXT_STEP))
        return PlantTeacher(envs, spec.decimation) if teacher else envs

    envs = {"without": stack(False), "teacher": stack(True)}
    actions = np.zeros((n_arms, *envs["without"].single_action_space.shape))
    for env in envs.values():
        env.reset(seed=0)
    best = interleaved_best(
        {
            name: functools.partial(seconds_per_call, env.step, [(actions,)] * policy_steps)
            for name, env in envs.items()
        },
        repeats,
    )
    for env in envs.values():
        env.close()
    return best
