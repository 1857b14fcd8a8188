"""Fill numba's cache before the xdist workers start (``conftest.pytest_configure``).

On a fresh clone every worker compiles every ``cache=True`` kernel it calls, both workers
the same kernels at the same time. Here two processes compile them once, in parallel, each
its share: ``python tests/warmup.py PART MARKERS`` runs the steps of ``PARTS[PART]``; a
step named ``"wait:X"`` waits until the other part has written ``MARKERS/X`` (the kernels
it compiles are then in the cache, loaded instead of compiled again), a step ``"mark:X"``
writes it. The steps go through the public API (the arrays the tests pass), so the cache
holds the signatures the tests call.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

WAIT_BOUND = 900.0  # s for the other part's marker


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
    import elastic_gym

    for env_id in elastic_gym.ENV_IDS:
        if env_id != "elastic_gym/TwoLinkRigid-v0":
            _steps(env_id)
    pulse = {"times": [0.0], "durations": [1e-3], "amplitudes": [[0.1, 0.1]]}
    _steps("elastic_gym/TwoLinkElastic-v0", torque_pulses=pulse)


def rk4() -> None:
    """An env on the RK4 integrator (its control period in one compiled call) and the
    Fourier task (its reference from Python)."""
    _steps("elastic_gym/TwoLinkElastic-v0", integrator="rk4")
    _steps("elastic_gym/TwoLinkElastic-v0", task="fourier")


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
        u = env.unwrapped
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
    state = [np.zeros((2, 2)) for _ in range(4)]
    arms.step(*state, np.zeros((2, 2)), 1e-3)
    arms.step(*state, np.zeros((2, 2)), 1e-3, np.zeros((2, 2)))
    arms.derivative(*state, np.zeros((2, 2)))


# The two chain kernels first, one per part, and a the accelerometers' complex-step
# kernel; then a compiles the RK4's kernels (they inline the chain's recursion: nothing
# of the other part's) and the complex-step Newton-Euler kernel while b compiles the env
# kernels of a rigid arm (every task and both models share their signature); then a
# compiles the env on the RK4 while b runs the other env ids and the closed loops (both
# complex kernels). Measured balance: studies/test_time/diary.md.
PARTS = {
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


def main(part: str, markers: Path) -> None:
    steps = PARTS[part]
    try:
        for step in steps:
            started = time.perf_counter()
            if step.startswith("mark:"):
                (markers / step[5:]).touch()
                continue
            if step.startswith("wait:"):
                while not (markers / step[5:]).exists():
                    if time.perf_counter() > started + WAIT_BOUND:
                        raise TimeoutError(f"no marker {step[5:]} after {WAIT_BOUND} s")
                    time.sleep(0.1)
            else:
                globals()[step]()
            print(f"{step} {time.perf_counter() - started:.1f} s", flush=True)
    finally:  # a failed part does not keep the other one waiting
        for step in steps:
            if step.startswith("mark:"):
                (markers / step[5:]).touch()


if __name__ == "__main__":
    main(sys.argv[1], Path(sys.argv[2]))
