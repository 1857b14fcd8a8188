"""Helpers shared by several test modules (import as ``from helpers import ...``)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml
from gymnasium.vector import AutoresetMode

import elastic_gym
from elastic_gym.arms import arm_view
from elastic_gym.benchmark.suite import SUITE_DIR
from elastic_gym.controllers import Controller, public_info
from elastic_gym.controllers.vector import VectorController
from elastic_gym.model import RobotModel
from elastic_gym.observers import vector
from elastic_gym.policy import PolicySpec, build_policy_env

ROOT = Path(__file__).resolve().parents[1]  # the checkout whose package the tests import
GRAVITY = 9.81
N_ARMS = 3
STEPS = 130  # one autoreset (episodes of 0.1 s at 1 kHz)


def fast_lane(cases, *fast) -> list:
    """``cases`` for ``pytest.mark.parametrize`` of which only those in ``fast`` run in the
    fast lane (``pytest -m "not slow"``); the others are marked ``slow``. A test repeated
    over robots, observers or options checks its representative cases at every commit and
    every case in the whole suite. A case of several arguments is a tuple."""
    unknown = [case for case in fast if case not in cases]
    assert not unknown, f"not among the cases: {unknown}"
    return [
        pytest.param(
            *(case if isinstance(case, tuple) else (case,)),
            marks=() if case in fast else pytest.mark.slow,
        )
        for case in cases
    ]


def checkout_env(*folders: Path, **variables: str) -> dict[str, str]:
    """This process's environment for a child that imports this checkout's package (and
    modules in ``folders``, such as user code a test wrote), plus ``variables``."""
    path = os.pathsep.join([str(ROOT), *map(str, folders)])
    return {**os.environ, "PYTHONPATH": path, **variables}


def cli_exit_code(args: list[str]) -> int:
    """The exit code of ``elastic-gym ARGS`` run in this process (usage errors exit
    through argparse)."""
    from elastic_gym.cli import main

    try:
        return main(args)
    except SystemExit as exc:
        return int(exc.code)


def cli_process(args: list[str], tmp_path: Path, **kwargs) -> subprocess.Popen:
    """``elastic-gym ARGS`` as a child process (its output piped, as text), importing this
    checkout's package and the user code a test wrote into ``tmp_path`` (``kwargs``: of
    ``Popen``, ``env`` replacing that environment)."""
    kwargs.setdefault("env", checkout_env(tmp_path))
    return subprocess.Popen(
        [sys.executable, "-m", "elastic_gym.cli", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kwargs,
    )


def folder_holder(folder: Path, *inside: str) -> subprocess.Popen:
    """A process that takes ``folder``'s lock (`elastic_gym.runtime.folder_lock`), runs the
    Python lines ``inside`` in it (``out``: the folder), prints ``locked`` and holds the
    lock for a minute (kill it when done)."""
    code = "\n".join(
        [
            "import time",
            "from elastic_gym.runtime.folder_lock import folder_lock",
            f"with folder_lock({str(folder)!r}) as out:",
            *(f"    {line}" for line in inside),
            "    print('locked', flush=True)",
            "    time.sleep(60)",
        ]
    )
    return subprocess.Popen(
        [sys.executable, "-c", code],
        env=checkout_env(),
        stdout=subprocess.PIPE,
        text=True,
    )


def synthetic_log_columns(rows: int = 1200, dt: float = 1e-3, state: bool = True) -> dict:
    """Columns of a plausible TwoLinkElastic log (not a simulation): smooth motions inside
    the limits, torques inside the limits, accelerometers reading about g."""
    t = np.arange(rows) * dt
    theta = np.stack([0.4 * np.sin(2 * np.pi * 0.5 * t), 1.0 + 0.3 * np.cos(2 * np.pi * t)], 1)
    dtheta = np.stack(
        [0.4 * np.pi * np.cos(np.pi * t), -0.6 * np.pi * np.sin(2 * np.pi * t)], axis=1
    )
    torque = np.stack([20.0 * np.sin(3 * t), -5.0 + 4.0 * np.cos(5 * t)], axis=1)
    wobble = 0.2 * np.sin(7 * t)[:, None]
    acc1 = np.hstack([wobble, 0.1 + 0 * wobble, GRAVITY + wobble])
    acc2 = np.hstack([GRAVITY * 0.6 + wobble, GRAVITY * 0.8 - wobble, 0.05 + 0 * wobble])
    columns = {"time": t}
    for j in range(2):
        columns[f"motor_position_{j + 1}"] = theta[:, j]
    for j in range(2):
        columns[f"torque_{j + 1}"] = torque[:, j]
    for name, acc in (("acc_link1", acc1), ("acc_link2", acc2)):
        for c, axis in enumerate("xyz"):
            columns[f"{name}_{axis}"] = acc[:, c]
    if state:
        for j in range(2):
            columns[f"q_{j + 1}"] = theta[:, j] - 0.01
            columns[f"dq_{j + 1}"] = dtheta[:, j]
            columns[f"theta_{j + 1}"] = theta[:, j]
            columns[f"dtheta_{j + 1}"] = dtheta[:, j]
    return columns


def write_csv_columns(path: Path, columns: dict, sidecar: str | None = None) -> Path:
    """A CSV log of ``columns`` (name -> array) and its sidecar text (default: the
    TwoLinkElastic robot at 1 ms)."""
    names = list(columns)
    values = np.column_stack([columns[name] for name in names])
    lines = [",".join(names)] + [",".join(map(repr, row)) for row in values.tolist()]
    path.write_text("\n".join(lines) + "\n")
    side = sidecar if sidecar is not None else "robot: TwoLinkElastic-v0\nsample_time: 0.001\n"
    path.with_suffix(".yaml").write_text(side)
    return path


# ------------------------------------------------------------ an independent elastic simulator
# For identification tests: not the envs' PyBullet plant but classical RK4 of x' = f(x) + G u
# (De Luca et al. 2007, eq. (4); model (2) with S) through RobotModel.elastic_dynamics
# (pinocchio's ABA), the torque held over each sample period, a motor PD with gravity
# compensation tracking a multi-sine reference plus a multi-sine torque dither, and the sensor
# model of the log format (quantized encoders; accelerometers f = R^T (a - g) + bias + white
# noise). Row k: sensors at t_k, the torque held from t_k to t_k+1.


def closed_loop_log(
    folder: Path, env_id: str, observer: str, seed: int, episode_time=0.3, **kwargs
):
    """Run eq. (13) on ``observer``'s online estimate in ``env_id`` (a LogRecorder under
    the observer wrapper); return (the online estimates, the path of the recorded log)."""
    from elastic_gym.controllers.registry import make_controller
    from elastic_gym.logs import LogRecorder, write_log
    from elastic_gym.observers import ObserverWrapper

    env = gym.make(env_id, episode_time=episode_time, **kwargs)
    recorder = LogRecorder(env)
    wrapped = ObserverWrapper(recorder, observer)
    base = env.unwrapped
    controller = make_controller("feedforward-state-feedback", base.model, base.control_dt)
    obs, info = wrapped.reset(seed=seed)
    controller.reset(obs, public_info(info))
    online = [info["estimate"]]
    done = False
    while not done:
        obs, _, terminated, truncated, info = wrapped.step(controller(obs, public_info(info)))
        online.append(info["estimate"])
        done = terminated or truncated
    path, _ = write_log(Path(folder) / "sim.csv", recorder.log())
    wrapped.close()
    return np.array(online), path


def multisine_reference(rng, low, high, base_hz: float = 0.1, harmonics: int = 5):
    """q_d(t), q_d'(t), q_d''(t): a random Fourier series in 60 % of [low, high]."""
    n = len(low)
    centre, half = (low + high) / 2, 0.3 * (high - low)
    k = np.arange(1, harmonics + 1)
    a = rng.normal(size=(harmonics, n)) / k[:, None]
    b = rng.normal(size=(harmonics, n)) / k[:, None]
    w = 2 * np.pi * base_hz * k
    t = np.linspace(0, 1 / base_hz, 4000)
    peak = np.max(np.abs(np.sin(np.outer(t, w)) @ a + np.cos(np.outer(t, w)) @ b), axis=0)
    a, b = a * half / peak, b * half / peak

    def reference(t: float):
        s, c = np.sin(w * t), np.cos(w * t)
        return centre + s @ a + c @ b, (c * w) @ a - (s * w) @ b, -(s * w**2) @ a - (c * w**2) @ b

    return reference


def multisine_dither(rng, amplitude, low_hz: float, high_hz: float, count: int = 40):
    """tau_d(t): ``count`` sines per joint at log-uniform frequencies, random phases, RMS
    ``amplitude`` per joint."""
    n = len(amplitude)
    f = np.exp(rng.uniform(np.log(low_hz), np.log(high_hz), size=(count, n)))
    phase = rng.uniform(0, 2 * np.pi, size=(count, n))
    scale = np.asarray(amplitude) * np.sqrt(2.0 / count)
    return lambda t: scale * np.sum(np.sin(2 * np.pi * f * t + phase), axis=0)


def simulate_log(
    plant: RobotModel,
    nominal: RobotModel,
    seconds: float,
    seed: int = 0,
    dt: float = 1e-3,
    substeps: int = 4,
    dither_fraction: float = 0.03,
    dither_hz: tuple[float, float] = (2.0, 25.0),
    bias_std: float = 0.02,
    noise_density: float = 1.5e-3,
    encoder_resolution: float = 2 * np.pi / 2**20,
    omega: float = 20.0,
    accelerometer_cutoff_hz: float | None = None,
    sensor_delay: int = 0,
) -> dict:
    """A closed-loop log of ``plant`` (controller on the ``nominal`` model), see above.
    ``accelerometer_cutoff_hz``: the readings through y_k = a y_k-1 + (1 - a) x_k (the
    envs' filter); ``sensor_delay``: the readings (and the controller) ``sensor_delay``
    samples late. Returns time, theta (the readings), torque, acceleration, bias, truth."""
    rng = np.random.default_rng(seed)
    n = plant.n
    low, high = np.asarray(plant.spec.workspace_low), np.asarray(plant.spec.workspace_high)
    reference = multisine_reference(rng, low, high)
    limit = plant.torque_limit
    dither = multisine_dither(rng, dither_fraction * limit, *dither_hz)
    q0 = reference(0.0)[0]
    J = nominal.B + np.diag(nominal.mass_matrix(q0))
    kp, kd = J * omega**2, 2 * 0.7 * J * omega
    x = np.concatenate([plant.static_motor_position(q0), q0, np.zeros(2 * n)])
    steps = round(seconds / dt)
    bias = bias_std * rng.standard_normal(3 * plant.n_sensors)
    sample_std = noise_density * np.sqrt(0.5 / dt)
    out = {k: np.zeros((steps + 1, n)) for k in ("theta", "torque", "q", "dq", "dtheta")}
    out["acceleration"] = np.zeros((steps + 1, 3 * plant.n_sensors))
    h = dt / substeps
    f = plant.elastic_dynamics
    alpha = (
        0.0
        if accelerometer_cutoff_hz is None
        else np.exp(-2 * np.pi * accelerometer_cutoff_hz * dt)
    )
    filtered = None
    line: list = []  # the readings' delay line, newest last
    for k in range(steps + 1):
        t = k * dt
        reading = np.round(x[:n] / encoder_resolution) * encoder_resolution
        previous = out["torque"][k - 1] if k else np.zeros(n)
        _, ddq = plant.elastic_accelerations(x, previous)
        forces = plant.accelerometer_readings(x[n : 2 * n], x[3 * n :], ddq)
        acceleration = forces + bias + sample_std * rng.standard_normal(len(forces))
        filtered = (
            acceleration if filtered is None else alpha * filtered + (1 - alpha) * acceleration
        )
        line.append((reading, filtered))
        theta_measured, out["acceleration"][k] = line[max(len(line) - 1 - sensor_delay, 0)]
        qd, dqd, ddqd = reference(t)
        g = nominal.gravity(qd)
        theta_d = qd + g / nominal.K
        tau = (
            g
            + (nominal.mass_matrix(qd) @ ddqd + nominal.B * ddqd)
            + kp * (theta_d - theta_measured)
            + kd * (dqd - x[2 * n : 3 * n])
            + dither(t)
        )
        tau = np.clip(tau, -limit, limit)
        out["theta"][k] = theta_measured
        out["torque"][k] = tau
        out["q"][k], out["dq"][k], out["dtheta"][k] = x[n : 2 * n], x[3 * n :], x[2 * n : 3 * n]
        for _ in range(substeps):  # RK4, the torque held
            k1 = f(x, tau)
            k2 = f(x + 0.5 * h * k1, tau)
            k3 = f(x + 0.5 * h * k2, tau)
            k4 = f(x + h * k3, tau)
            x = x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    out["time"] = np.arange(steps + 1) * dt
    out["bias"] = bias
    return out


def shipped_suite_data() -> dict:
    """The shipped benchmark suite ``elastic-gym-v1`` as YAML data."""
    return yaml.safe_load((SUITE_DIR / "elastic-gym-v1.yaml").read_text())


def tiny_suite_data() -> dict:
    """The shipped suite cut to two cells of 0.1 s on TwoLinkElastic (10 seeds)."""
    data = shipped_suite_data()
    data["duration"] = 0.1
    data["robots"] = {"two-link": data["robots"]["two-link"]}
    data["tasks"] = {"smooth": data["tasks"]["smooth"]}
    data["categories"] = {
        "nominal": {**data["categories"]["nominal"], "cells": [{"task": "smooth", "label": "s"}]},
        "latency": {
            **data["categories"]["latency"],
            "cells": [{"task": "smooth", "label": "d2", "plant": {"sensor_delay": 2}}],
        },
        # differs from the nominal cell only in per-arm kwargs: one world runs both
        "link-model": {
            **data["categories"]["link-model"],
            "cells": [
                {"task": "smooth", "label": "m", "plant": {"plant_scaling": {"link_mass": 1.1}}}
            ],
        },
    }
    data["precision"]["tasks"] = ["smooth"]
    return data


# ------------------------------------------------------------ shared by several modules


class GravityPD(Controller):
    """Test controller: PD + gravity compensation (elastic: on the motor, rigid: on the link)."""

    name = "gravity-pd"

    def __init__(self, model, dt, kp: float = 400.0, kd: float = 40.0) -> None:
        super().__init__(model, dt)
        self.kp, self.kd = kp, kd

    def __call__(self, obs, info):
        ref = info["reference"]
        if self.elastic:
            theta, _, dtheta, _ = self.split_state(obs)
            g = self.model.gravity(ref["q"])
            theta_d = ref["q"] + g / self.model.K
            return g + self.kp * (theta_d - theta) + self.kd * (ref["dq"] - dtheta)
        q, dq = self.split_state(obs)
        return self.model.gravity(q) + self.kp * (ref["q"] - q) + self.kd * (ref["dq"] - dq)


def leaves(value, out: list) -> list:
    if isinstance(value, dict):
        for key in sorted(value):
            out.append(key)
            leaves(value[key], out)
    elif isinstance(value, tuple):
        for item in value:
            leaves(item, out)
    else:
        array = np.asarray(value)
        out.append(
            (
                array.dtype.str,
                array.shape,
                array.tobytes() if array.dtype != object else repr(value),
            )
        )
    return out


def flat(value) -> np.ndarray:
    if isinstance(value, dict):
        return np.concatenate([flat(value[k]) for k in sorted(value)])
    if value is None or isinstance(value, str):
        return np.array([hash(value) % 997], dtype=float)
    return np.atleast_1d(np.asarray(value, dtype=float)).ravel()


def arm_row(batched: dict, i: int) -> dict:
    """Arm i of a batched observation or info (masks dropped)."""
    return {
        k: arm_row(v, i) if isinstance(v, dict) else v[i]
        for k, v in batched.items()
        if not k.startswith("_")
    }


def simulate(env: gym.Env, controller, steps: int, seed: int = 0, options=None) -> dict:
    """Run ``controller`` on ``env`` (wrapped with a state source); return link trajectories."""
    obs, info = env.reset(seed=seed, options=options)
    controller.reset(obs, public_info(info))
    q, q_d = [], []
    for _ in range(steps):
        obs, _, terminated, _, info = env.step(controller(obs, public_info(info)))
        assert not terminated, info["termination_reason"]
        q.append(info["true_state"]["q"])
        q_d.append(info["reference"]["q"])
    env.close()
    q, q_d = np.array(q), np.array(q_d)
    return {"q": q, "q_d": q_d, "error": q - q_d}


def rigid_scenario(**changes) -> dict:
    data = {
        "name": "rigid-test",
        "duration": 0.3,
        "envs": [{"id": "TwoLinkRigid-v0", "kwargs": {"task": "regulation"}}],
        "controllers": [{"name": "gravity-pd", "class": GravityPD}],
        "state_sources": [True, "finite-difference"],
    }
    data.update(changes)
    return data


def jobs_here(monkeypatch) -> None:
    """With ``monkeypatch`` (a fixture's, or ``pytest.MonkeyPatch.context()`` in a module
    fixture): ``workers=1`` runs its jobs in this process, as it does for jobs that refer to
    ``__main__`` (the ``jobs_in_this_process`` fixture of conftest)."""
    import importlib

    def here(*objects) -> bool:
        return True

    for module in ("elastic_gym.runtime.parallel", "elastic_gym.evaluation.execute"):
        monkeypatch.setattr(importlib.import_module(module), "refers_to_main", here)


def children(pid: int) -> list[int]:
    """Process ids whose parent is ``pid`` (Linux /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def descendants(pid: int) -> list[int]:
    """Process ids below ``pid``: its children, theirs, and so on (Linux /proc)."""
    found, parents = [], [pid]
    while parents:
        below = [child for parent in parents for child in children(parent)]
        found += below
        parents = below
    return found


def is_multiprocessing_helper(pid: int) -> bool:
    """multiprocessing's resource tracker or a fork server: helper processes that end
    when the process that started them has ended."""
    try:
        command = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False
    return b"resource_tracker" in command or b"forkserver" in command


def workers_of(pid: int) -> list[int]:
    """The worker processes below ``pid``: its descendants but multiprocessing's helpers
    among its children (a fork server's children, forked from it, share its command)."""
    helpers = {child for child in children(pid) if is_multiprocessing_helper(child)}
    return [p for p in descendants(pid) if p not in helpers]


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


NOISE_FREE = {"encoder": {"resolution": 0.0, "noise_std": 0.0}, "accelerometer": "ideal"}
ELASTIC_IDS = [i for i in elastic_gym.ENV_IDS if "Elastic" in i]


def make_noise_free(env_id: str, **kwargs) -> gym.Env:
    """An env whose sensors are exact (ideal encoders and accelerometers)."""
    return gym.make(env_id, **{**NOISE_FREE, **kwargs})


def same_metric(a, b) -> bool:
    """Two metric values equal (NaN equal to NaN; floats to 1e-12 relative)."""
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or a == b or abs(a - b) <= 1e-12 * abs(b)
    return a == b


# ------------------------------------------------------------ policy stacks
def policy_spec(
    env_id: str, state: str = "true", env_kwargs: dict | None = None, **fields
) -> PolicySpec:
    """A policy spec from its fields; ``frame_stack`` of a state source becomes its
    observation's ``frames`` (the spec keeps ``frame_stack`` for raw sensors)."""
    frames = fields.pop("frame_stack", None)
    if frames is not None and state != "sensors":
        observation = fields.pop("observation", None) or {}
        observation = observation if isinstance(observation, dict) else observation.to_dict()
        fields["observation"] = {**observation, "frames": frames}
    elif frames is not None:
        fields["frame_stack"] = frames
    return PolicySpec(env_id=env_id, state=state, env_kwargs=env_kwargs or {}, **fields)


def policy_env(env_id: str, state: str = "true", env_kwargs: dict | None = None, **fields):
    """The policy stack of a spec on one env (with the critic's inputs if it has some)."""
    spec = policy_spec(env_id, state, env_kwargs, **fields)
    return build_policy_env(spec, spec.make_env(), critic=spec.critic)


def policy_vec_env(
    env_id: str,
    n_arms: int,
    state: str = "true",
    env_kwargs: dict | None = None,
    autoreset_mode: AutoresetMode = AutoresetMode.DISABLED,
    teacher: bool = False,
    **fields,
):
    """The policy stack of a spec on ``n_arms`` arms of one world (with the critic's inputs
    if it has some, the plant teacher's labels with ``teacher``)."""
    spec = policy_spec(env_id, state, env_kwargs, **fields)
    envs = build_policy_env(spec, spec.make_env(n_arms, autoreset_mode=autoreset_mode), spec.critic)
    if teacher:
        from elastic_gym.training.teacher import PlantTeacher

        envs = PlantTeacher(envs, spec.decimation)
    return envs


def spec_env(spec: PolicySpec, env_kwargs: dict | None = None, critic: bool = False):
    """A spec's stack on one env, ``env_kwargs`` updating the spec's."""
    return build_policy_env(spec, spec.make_env(env_kwargs=env_kwargs), critic=critic)


def relative_gap(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / max(1.0, np.abs(b).max()))


def closed_loop_gap(env_id: str, batched: VectorController, singles: list[Controller]) -> float:
    """Drive a vector env with ``batched``; the largest relative gap between an arm's torque
    and its own single controller's, over a closed loop through one autoreset (the arms'
    torques differ: their own seeds give them their own references)."""
    envs = vector.TrueStateWrapper(
        gym.make_vec(
            env_id, num_envs=N_ARMS, vectorization_mode="vector_entry_point", episode_time=0.1
        )
    )
    obs, info = envs.reset(seed=11)
    arms = np.arange(N_ARMS)
    restart, ended = arms, np.zeros(N_ARMS, dtype=bool)
    worst = spread = 0.0
    resets = 0
    for _ in range(STEPS):
        public = public_info(info)
        if len(restart):
            batched.reset_arms(obs, public, restart)
            for i in restart:
                singles[i].reset(arm_view(obs, i), arm_view(public, i))
        resets += len(restart)
        torque = batched(obs, public)
        spread = max(spread, relative_gap(torque[0], torque[1]))
        assert torque.shape == (N_ARMS, envs.unwrapped.batch.n_joints)
        for i, single in enumerate(singles):
            worst = max(
                worst, relative_gap(torque[i], single(arm_view(obs, i), arm_view(public, i)))
            )
        obs, _, terminated, truncated, info = envs.step(torque)
        assert not terminated.any(), info["termination_reason"]
        restart = np.flatnonzero(ended)  # arms the env has just reset (NEXT_STEP autoreset)
        ended = terminated | truncated
    envs.close()
    assert resets == 2 * N_ARMS and spread > 1e-3
    return worst


def step_in_lockstep(envs, singles: list, next_actions, steps: int) -> set[str]:
    """Step a vector env and its single-env twins together for ``steps`` steps (actions from
    ``next_actions()``): arm i's observation, reward, flags and info equal single env i's at
    every step, NEXT_STEP autoresets followed (the single env reset without a seed). The
    termination reasons seen."""
    ended = np.zeros(len(singles), dtype=bool)
    reasons: set[str] = set()
    for _ in range(steps):
        actions = next_actions()
        obs, reward, terminated, truncated, info = envs.step(actions)
        for i, env in enumerate(singles):
            if ended[i]:  # NEXT_STEP autoreset: the single env is reset without a seed
                expected = (*env.reset(), 0.0, False, False)
                expected = (expected[0], expected[2], expected[3], expected[4], expected[1])
            else:
                expected = env.step(actions[i])
            single_obs, single_reward, single_term, single_trunc, single_info = expected
            assert np.array_equal(flat(arm_row(obs, i)), flat(single_obs))
            assert reward[i] == single_reward
            assert (terminated[i], truncated[i]) == (single_term, single_trunc)
            assert np.array_equal(flat(arm_row(info, i)), flat(single_info))
            if single_term:
                reasons.add(single_info["termination_reason"])
        ended = terminated | truncated
    return reasons
