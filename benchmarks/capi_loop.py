"""The physics substeps compiled: PyBullet's own C API called from a numba kernel.

    python benchmarks/capi_loop.py            # TwoLinkElastic, N = 1 and 64, 0.5 ms and 1/16 ms
    python benchmarks/capi_loop.py --quick

The floor of every ratio in ``bench.py`` is the bare Python loop over PyBullet's Python
functions (per substep: ``setJointMotorControlArray(TORQUE)`` + ``stepSimulation`` +
``getJointStates`` per arm). The simulator steps its world through PyBullet's C API from
compiled code instead (`elastic_gym.envs.bullet_capi`), with the same commands.

This script measures that floor: two worlds made the same way are stepped with the same
torques, one through the Python functions, one by
`substep` in a compiled loop; it checks that their
joint states stay equal bit for bit and prints the cost per arm and control period of
each loop (CPU time, best of interleaved blocks, as ``bench.py``).
"""

from __future__ import annotations

import argparse

import numpy as np
import pybullet as p
from numba import njit
from timing import (
    ensure_single_thread_blas,
    interleaved_best,
    machine_line,
    print_table,
    seconds_per_call,
)

from elastic_gym.envs import bullet_capi
from elastic_gym.robots.catalog import get_robot
from elastic_gym.robots.urdf_tools import urdf_without_limits


@njit(cache=True)
def compiled_substeps(slot, world, torques, none, n_substeps, states):
    """``n_substeps`` physics steps of every arm under its torques (N, n) (``none``: an
    (N, 0) array, no extra torque); q, q' of the last one into ``states`` (flat)."""
    for _ in range(n_substeps):
        bullet_capi.substep(slot[0], world, torques, none, states)


class World:
    """N arms of a robot in a world of the Python API: fixed bases 2 m apart, inertias
    from the URDF, default motors off."""

    def __init__(self, robot: str, n_arms: int, physics_dt: float) -> None:
        spec = get_robot(robot)
        urdf = urdf_without_limits(spec.urdf)
        c = self.client = p.connect(p.DIRECT)
        p.setGravity(*spec.gravity, physicsClientId=c)
        p.setTimeStep(physics_dt, physicsClientId=c)
        self.bodies = [
            p.loadURDF(
                urdf,
                basePosition=(2.0 * k, 0.0, 0.0),
                useFixedBase=True,
                flags=p.URDF_USE_INERTIA_FROM_FILE,
                physicsClientId=c,
            )
            for k in range(n_arms)
        ]
        infos = {
            info[1].decode(): info
            for info in (
                p.getJointInfo(self.bodies[0], j, physicsClientId=c)
                for j in range(p.getNumJoints(self.bodies[0], physicsClientId=c))
            )
        }
        self.joints = [infos[name][0] for name in spec.joint_names]
        self.n_joints = len(self.joints)
        for body in self.bodies:
            p.setJointMotorControlArray(
                body, self.joints, p.VELOCITY_CONTROL, forces=[0.0] * self.n_joints,
                physicsClientId=c,
            )  # fmt: skip
        self.world = bullet_capi.world_arrays(c, self.bodies, self.joints)
        self.states = np.empty(2 * n_arms * self.n_joints)

    def joint_states(self) -> np.ndarray:
        """q, q' of every joint, (N, 2 n)."""
        c = self.client
        return np.array(
            [
                [
                    x
                    for state in p.getJointStates(body, self.joints, physicsClientId=c)
                    for x in state[:2]
                ]
                for body in self.bodies
            ]
        )

    def close(self) -> None:
        p.disconnect(self.client)


class PythonWorld(World):
    """Stepped through PyBullet's Python functions: the bare loop of
    ``bench.BarePyBullet`` / ``batched.BareBatch``."""

    def step(self, torques: np.ndarray, n_substeps: int) -> None:
        """``n_substeps`` physics steps under ``torques`` (N, n)."""
        c, joints, forces = self.client, self.joints, torques.tolist()
        for _ in range(n_substeps):
            for body, arm_forces in zip(self.bodies, forces, strict=True):
                p.setJointMotorControlArray(
                    body, joints, p.TORQUE_CONTROL, forces=arm_forces, physicsClientId=c
                )
            p.stepSimulation(physicsClientId=c)
            for body in self.bodies:
                p.getJointStates(body, joints, physicsClientId=c)


class CompiledWorld(World):
    """Stepped through PyBullet's C API by `compiled_substeps`."""

    def __init__(self, robot: str, n_arms: int, physics_dt: float) -> None:
        super().__init__(robot, n_arms, physics_dt)
        slot = bullet_capi.client_slot(self.client)
        if slot is None:
            raise SystemExit("PyBullet's C handles cannot be read here (see bullet_capi)")
        self.slot = slot

    def step(self, torques: np.ndarray, n_substeps: int) -> None:
        """``n_substeps`` physics steps under ``torques`` (N, n), in one compiled call."""
        none = np.zeros((torques.shape[0], 0))
        compiled_substeps(self.slot, self.world, torques, none, n_substeps, self.states)


def compare(robot: str, n_arms: int, physics_dt: float, block: int, repeats: int) -> dict:
    """Bit-equality of the two worlds after ``block`` control periods and the cost of each
    loop per arm and 1 ms control period."""
    n_substeps = round(1e-3 / physics_dt)
    worlds = {
        "python": PythonWorld(robot, n_arms, physics_dt),
        "compiled": CompiledWorld(robot, n_arms, physics_dt),
    }
    rng = np.random.default_rng(0)
    torques = 0.05 * rng.standard_normal((block, n_arms, worlds["python"].n_joints))
    for world in worlds.values():
        for tau in torques:
            world.step(tau, n_substeps)
    equal = np.array_equal(worlds["python"].joint_states(), worlds["compiled"].joint_states())
    costs = interleaved_best(
        {
            name: (
                lambda w=world: (
                    seconds_per_call(w.step, [(tau, n_substeps) for tau in torques]) / n_arms
                )
            )
            for name, world in worlds.items()
        },
        repeats,
    )
    for world in worlds.values():
        world.close()
    return {**costs, "equal": equal, "substeps": n_substeps}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robot", default="two_link_elastic")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    ensure_single_thread_blas()
    block, repeats = (100, 3) if args.quick else (400, 7)
    print(machine_line())
    rows = []
    for n_arms in (1, 64):
        for physics_dt in (0.5e-3, 1e-3 / 16):
            c = compare(args.robot, n_arms, physics_dt, max(5, block // n_arms), repeats)
            rows.append(
                [
                    str(n_arms),
                    str(c["substeps"]),
                    f"{c['python'] * 1e6:.3g}",
                    f"{c['compiled'] * 1e6:.3g}",
                    f"{c['python'] / c['compiled']:.2f}",
                    "yes" if c["equal"] else "NO",
                ]
            )
    print_table(
        f"Python bare loop / compiled C API loop, {args.robot}, per arm and 1 ms control period",
        [
            "arms",
            "substeps per ms",
            "Python loop [us]",
            "compiled loop [us]",
            "ratio",
            "same states bit for bit",
        ],
        rows,
    )


if __name__ == "__main__":
    main()
