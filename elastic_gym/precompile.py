"""Compile the simulation's kernels into numba's cache ahead of their first use.

A ``cache=True`` kernel compiles at its first call in a process whose cache has no code
for it (a first env step after an install waits half a minute to a minute); later
processes load it. `precompile` makes that first call for everything the package
compiles, through the public API with the argument types the package passes: the chain's
kernels (real, and complex for the EKF's and the inverse dynamics' derivatives), every env
id's, the RK4 integrator's, and the closed loops of eq. (13) on De Luca's observer and the
EKF. ``elastic-gym precompile`` is its command (once after an install, or an image build).

With ``jobs=2`` two processes split the steps (`PARTS`): ``"wait:X"`` waits until the other
has written marker ``X`` (the kernels of its steps before ``"mark:X"`` are then cached:
loaded, not compiled twice). With ``jobs=1`` one process runs them (`one_process_order`).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

WAIT_BOUND = 900.0  # s a part waits for the other part's marker
StepTimes = list[tuple[str, float, int]]  # (step, wall seconds, kernels compiled)
# A part's process. Not ``python -m elastic_gym.precompile``: with this module as
# ``__main__`` the RK4 integrator's kernels compiled 1.5 times slower (cause not found).
CHILD = (
    "import sys; from pathlib import Path; from elastic_gym.precompile import run_part; "
    "run_part(sys.argv[1], Path(sys.argv[2]))"
)


def _chain():
    from elastic_gym.model import RobotModel
    from elastic_gym.robots.catalog import get_robot

    model = RobotModel(get_robot("two_link_elastic"))
    rng = np.random.default_rng(0)
    q, dq, ddq, tau = (rng.uniform(-1.0, 1.0, (2, model.n)) for _ in range(4))
    return model.chain, q, dq, ddq, tau


def dynamics() -> None:
    """The Newton-Euler kernel in every mode."""
    chain, q, dq, ddq, tau = _chain()
    chain.gravity(q)
    chain.mass_and_bias(q, dq)
    chain.rnea(q, dq, ddq)
    chain.forward_dynamics(q, dq, tau)
    chain.forward_dynamics(q, dq, tau, -0.01 * np.eye(chain.n))


def dynamics_complex() -> None:
    """The Newton-Euler kernel on complex numbers (the complex step of rnea_tangent)."""
    chain, q, dq, ddq, tau = _chain()
    chain.rnea_tangent((q, dq, ddq), (dq, ddq, tau))


def sensors() -> None:
    """The accelerometer kernel in every mode, and eq. (11)."""
    chain, q, dq, ddq, _ = _chain()
    readings = chain.specific_forces(q, dq, ddq)
    chain.accelerometer_maps(q, dq)
    chain.acceleration_from_readings(q, dq, readings, 0.1, 0.05)


def sensors_complex() -> None:
    """The accelerometer kernel on complex numbers (specific_forces_tangent)."""
    chain, q, dq, ddq, _ = _chain()
    chain.specific_forces_tangent((q, dq, ddq), (dq, ddq, q))


def _steps(env_id: str, **kwargs) -> None:
    import gymnasium as gym

    env = gym.make(env_id, **kwargs)
    env.reset(seed=0)
    for _ in range(3):
        env.step(env.action_space.sample())
    env.close()


def rigid() -> None:
    """A rigid arm (q'' and the readings from Python), which compiles the env's kernels
    and the control period's (the transmission's too: a rigid arm's link friction)."""
    _steps("elastic_gym/TwoLinkRigid-v0")


def elastic() -> None:
    """The other env ids (model (2)'s KR15 shares the env kernels' signatures with
    model (1)) and a link torque pulse."""
    from elastic_gym import ENV_IDS

    for env_id in ENV_IDS:
        if env_id != "elastic_gym/TwoLinkRigid-v0":
            _steps(env_id)
    pulse = {"times": [0.0], "durations": [1e-3], "amplitudes": [[0.1, 0.1]]}
    _steps("elastic_gym/TwoLinkElastic-v0", torque_pulses=pulse)


def rk4() -> None:
    """An env on the RK4 integrator (its control period in one compiled call) and the
    Fourier task (its reference from Python), with the torque dither of a recorded
    identification excitation."""
    _steps("elastic_gym/TwoLinkElastic-v0", integrator="rk4")
    _steps("elastic_gym/TwoLinkElastic-v0", task="fourier")
    _steps("elastic_gym/TwoLinkElastic-v0", task="fourier", task_options={"dither": {}})


def loops() -> None:
    """The closed loop of eq. (13) (its torsion filter) on the De Luca observer (its
    row-stacked products) and on the EKF, a few control periods each; the inverse
    dynamics planned along a trajectory (the torsion filter's loop over periods)."""
    import gymnasium as gym

    from elastic_gym.controllers.base import public_info
    from elastic_gym.controllers.invdyn import InverseDynamics
    from elastic_gym.controllers.registry import make_controller
    from elastic_gym.observers import ObserverWrapper

    for observer in ("deluca", "ekf"):
        env = ObserverWrapper(gym.make("elastic_gym/TwoLinkElastic-v0"), observer)
        u: Any = env.unwrapped
        controller = make_controller("feedforward-state-feedback", u.model, u.control_dt)
        obs, info = env.reset(seed=0)
        controller.reset(obs, public_info(info))
        for _ in range(3):
            obs, _, _, _, info = env.step(controller(obs, public_info(info)))
        env.close()
    times = np.arange(3) * u.control_dt
    InverseDynamics(u.model).trajectory(times, np.zeros((3, 5, u.model.n)))


def integrator() -> None:
    """The RK4 integrator of the arms: a control period (with and without link torques)
    and the right-hand side."""
    from elastic_gym.envs.plant import PlantArray
    from elastic_gym.model import RobotModel
    from elastic_gym.model.integrator import ArmIntegrator
    from elastic_gym.robots.catalog import get_robot

    plants = PlantArray([RobotModel(get_robot("two_link_elastic"))] * 2)
    arms = ArmIntegrator(plants.chain, plants.transmission, None, True)
    theta, dtheta, q, dq, tau = (np.zeros((2, 2)) for _ in range(5))
    arms.step(theta, dtheta, q, dq, tau, 1e-3)
    arms.step(theta, dtheta, q, dq, tau, 1e-3, np.zeros((2, 2)))
    arms.derivative(theta, dtheta, q, dq, tau)


STEPS: dict[str, Callable[[], None]] = {
    step.__name__: step
    for step in (
        dynamics,
        sensors,
        sensors_complex,
        integrator,
        dynamics_complex,
        rigid,
        elastic,
        rk4,
        loops,
    )
}

# The two chain kernels first, one per part, and part a the accelerometers' complex-step
# kernel; then a compiles the RK4's kernels (they inline the chain's recursion: nothing
# of the other part's) and the complex-step Newton-Euler kernel while b compiles the env
# kernels of a rigid arm (every task and both models share their signature); then a
# compiles the env on the RK4 while b runs the other env ids and the closed loops (both
# complex kernels). The parts end within a few seconds of each other on 2 cores.
PARTS: dict[str, list[str]] = {
    "a": [
        "dynamics",
        "mark:dynamics",
        "sensors_complex",
        "mark:sensors_complex",
        "integrator",
        "dynamics_complex",
        "mark:dynamics_complex",
        "wait:rigid",
        "rk4",
    ],
    "b": [
        "sensors",
        "wait:dynamics",
        "rigid",
        "mark:rigid",
        "elastic",
        "wait:sensors_complex",
        "wait:dynamics_complex",
        "loops",
    ],
}


def one_process_order(parts: dict[str, list[str]] = PARTS) -> list[str]:
    """The steps of all parts in one sequence that honours their waits: each part runs
    until it waits for a marker not yet written, then the next part runs."""
    position = dict.fromkeys(parts, 0)
    marked: set[str] = set()
    order: list[str] = []
    while any(position[part] < len(steps) for part, steps in parts.items()):
        moved = False
        for part, steps in parts.items():
            while position[part] < len(steps):
                step = steps[position[part]]
                kind, _, name = step.rpartition(":")
                if kind == "wait" and name not in marked:
                    break
                if kind == "mark":
                    marked.add(name)
                elif not kind:
                    order.append(step)
                position[part] += 1
                moved = True
        if not moved:
            raise ValueError(f"the parts wait for markers no part writes: {position}")
    return order


def _timed(step: str) -> tuple[float, int]:
    """Run one step; its wall time and how many kernels numba compiled for it (the rest
    it loaded from the cache)."""
    from numba.core import event

    started = time.perf_counter()
    with event.install_recorder("numba:compile") as recorder:
        STEPS[step]()
    compiled = sum(1 for _, data in recorder.buffer if data.is_start)
    return time.perf_counter() - started, compiled


def run_part(part: str, markers: Path) -> None:
    """Run the steps of ``PARTS[part]``, printing ``STEP SECONDS COMPILED`` per step."""
    steps = PARTS[part]
    try:
        for step in steps:
            kind, _, name = step.rpartition(":")
            if kind == "mark":
                (markers / name).touch()
            elif kind == "wait":
                deadline = time.monotonic() + WAIT_BOUND
                while not (markers / name).exists():
                    if time.monotonic() > deadline:
                        raise TimeoutError(f"no marker {name} after {WAIT_BOUND:.0f} s")
                    time.sleep(0.05)
            else:
                seconds, compiled = _timed(step)
                print(f"{step} {seconds:.2f} {compiled}", flush=True)
    finally:  # a failed part does not keep the other one waiting
        for step in steps:
            kind, _, name = step.rpartition(":")
            if kind == "mark":
                (markers / name).touch()


def precompile(
    jobs: int = 2, bound: float | None = None, progress: Callable[[str], None] | None = None
) -> StepTimes:
    """Compile every kernel of the package into numba's cache (see the module docstring).

    Args:
        jobs: 1 (this process) or 2 (two processes at once, each a share of the steps).
        bound: seconds the two processes may take before they are killed (None: no bound).
        progress: called with a line per finished part (``jobs=2``) or step (``jobs=1``).

    Returns:
        Per step, its wall time and the number of kernels it compiled (0: all loaded).

    Raises:
        ValueError: ``jobs`` is not 1 or 2.
        RuntimeError: a step failed or the bound was reached (the message holds the end
            of the failed process's output).
    """
    if jobs not in (1, 2):
        raise ValueError(f"jobs must be 1 or 2, got {jobs!r}")
    say = progress or (lambda line: None)
    if jobs == 1:
        times = []
        for step in one_process_order():
            times.append((step, *_timed(step)))
            say(_format(times[-1:]))
        return times
    return _two_processes(bound, say)


def _format(times: StepTimes) -> str:
    """``STEP 1.2 s (3 compiled), ...``"""
    return ", ".join(
        f"{step} {seconds:.1f} s ({compiled} compiled)" for step, seconds, compiled in times
    )


def _two_processes(bound: float | None, say: Callable[[str], None]) -> StepTimes:
    """`PARTS` in two child processes importing this very package (whatever ``sys.path``
    their working folder would give them)."""
    package_root = str(Path(__file__).resolve().parent.parent)
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([package_root, os.environ.get("PYTHONPATH", "")]),
    }
    deadline = None if bound is None else time.monotonic() + bound
    times: StepTimes = []
    with tempfile.TemporaryDirectory() as markers:
        logs = {part: Path(markers) / f"{part}.log" for part in PARTS}
        children = {}
        for part, log in logs.items():
            with log.open("w") as handle:
                children[part] = subprocess.Popen(
                    [sys.executable, "-c", CHILD, part, markers],
                    env=env,
                    stdout=handle,
                    stderr=subprocess.STDOUT,
                    stdin=subprocess.DEVNULL,
                )
        failed = []
        for part, child in children.items():
            try:
                code = child.wait(
                    None if deadline is None else max(0.1, deadline - time.monotonic())
                )
            except subprocess.TimeoutExpired:
                child.kill()
                code = child.wait()
            lines = logs[part].read_text().splitlines()
            done = [parsed for line in lines if (parsed := _parsed(line)) is not None]
            times.extend(done)
            say(f"part {part}: {_format(done)}")
            if code != 0:
                failed.append(f"part {part} (exit {code}):\n" + "\n".join(lines[-15:]))
    if failed:
        raise RuntimeError("precompile failed in " + "\n".join(failed))
    return times


def _parsed(line: str) -> tuple[str, float, int] | None:
    """A step's line of `run_part` (``STEP SECONDS COMPILED``), or None for other output."""
    words = line.split()
    if len(words) == 3 and words[0] in STEPS:
        try:
            return words[0], float(words[1]), int(words[2])
        except ValueError:
            return None
    return None
