"""The physics substeps compiled: PyBullet's own C API called from a numba kernel.

    python benchmarks/capi_loop.py            # TwoLinkElastic, N = 1 and 64, 0.5 ms and 1/16 ms
    python benchmarks/capi_loop.py --quick

The floor of every ratio in ``bench.py`` is the bare Python loop over PyBullet's Python
functions (per substep: ``setJointMotorControlArray(TORQUE)`` + ``stepSimulation`` +
``getJointStates`` per arm). PyBullet's extension module also exports its C client API
(``b3JointControlCommandInit2``, ``b3InitStepSimulationCommand``,
``b3SubmitClientCommandAndWaitStatus``, ``b3RequestActualStateCommandInit``,
``b3GetJointState``, ...): the same commands the Python functions build. A numba kernel
can call them directly, so a whole control period's substeps (and the transmission
kernel between them) could run without returning to Python.

This script measures what that is worth before the simulator is built on it: two worlds
made the same way, one through the Python API, one through the C API (set up with
ctypes, stepped by a compiled kernel), are stepped with the same torques; it checks that
their joint states stay equal bit for bit and prints the cost per arm and control period
of each loop (CPU time, best of interleaved blocks, as ``bench.py``).

What the Python API's world handle is cannot be read (PyBullet keeps its clients in a
static table), so a simulator using the compiled loop must create and set up its world
through the C API itself.
"""

from __future__ import annotations

import argparse
import ctypes

import llvmlite.binding as llvm
import numpy as np
import pybullet as p
from numba import njit, types
from timing import (
    ensure_single_thread_blas,
    interleaved_best,
    machine_line,
    print_table,
    seconds_per_call,
)

from elastic_gym.robots.catalog import get_robot
from elastic_gym.robots.urdf_tools import urdf_without_limits

_LIB = ctypes.CDLL(p.__file__)  # the loaded extension module: the same symbols
_POINTER = types.intp  # handles passed as integers (same registers on x86-64 and arm64)
_TORQUE_CONTROL, _VELOCITY_CONTROL = 1, 0  # CONTROL_MODE_* of PyBullet's C API


def _external(name: str, signature):
    """A C API function numba calls by name (the address bound to a symbol of its own)."""
    symbol = f"elastic_gym_bench_{name}"
    llvm.add_symbol(symbol, ctypes.cast(getattr(_LIB, name), ctypes.c_void_p).value)
    return types.ExternalFunction(symbol, signature)


_submit = _external("b3SubmitClientCommandAndWaitStatus", _POINTER(_POINTER, _POINTER))
_step_command = _external("b3InitStepSimulationCommand", _POINTER(_POINTER))
_control_command = _external(
    "b3JointControlCommandInit2", _POINTER(_POINTER, types.intc, types.intc)
)
_set_torque = _external(
    "b3JointControlSetDesiredForceTorque", types.intc(_POINTER, types.intc, types.double)
)
_state_command = _external("b3RequestActualStateCommandInit", _POINTER(_POINTER, types.intc))
_joint_state = _external("b3GetJointState", types.intc(_POINTER, _POINTER, types.intc, _POINTER))


@njit
def compiled_substeps(client, bodies, dofs, joints, torques, n_substeps, states, sensor):
    """``n_substeps`` physics steps of every arm under its motor torques (N, n); q, q' of
    the last one into ``states`` (N, 2 n). ``sensor``: 9 doubles (``b3JointSensorState``)."""
    for _ in range(n_substeps):
        for k in range(bodies.shape[0]):
            command = _control_command(client, bodies[k], _TORQUE_CONTROL)
            for j in range(dofs.shape[0]):
                _set_torque(command, dofs[j], torques[k, j])
            _submit(client, command)
        _submit(client, _step_command(client))
        for k in range(bodies.shape[0]):
            status = _submit(client, _state_command(client, bodies[k]))
            for j in range(joints.shape[0]):
                _joint_state(client, status, joints[j], sensor.ctypes.data)
                states[k, 2 * j] = sensor[0]
                states[k, 2 * j + 1] = sensor[1]


def _declare(name: str, restype, *argtypes):
    function = getattr(_LIB, name)
    function.restype, function.argtypes = restype, list(argtypes)
    return function


_V, _I, _D = ctypes.c_void_p, ctypes.c_int, ctypes.c_double
_connect = _declare("b3ConnectPhysicsDirect", _V)
_disconnect = _declare("b3DisconnectSharedMemory", None, _V)
_submit_c = _declare("b3SubmitClientCommandAndWaitStatus", _V, _V, _V)
_physics_parameters = _declare("b3InitPhysicsParamCommand", _V, _V)
_set_gravity = _declare("b3PhysicsParamSetGravity", _I, _V, _D, _D, _D)
_set_time_step = _declare("b3PhysicsParamSetTimeStep", _I, _V, _D)
_load_urdf = _declare("b3LoadUrdfCommandInit", _V, _V, ctypes.c_char_p)
_fixed_base = _declare("b3LoadUrdfCommandSetUseFixedBase", _I, _V, _I)
_urdf_flags = _declare("b3LoadUrdfCommandSetFlags", _I, _V, _I)
_start_position = _declare("b3LoadUrdfCommandSetStartPosition", _I, _V, _D, _D, _D)
_body_index = _declare("b3GetStatusBodyIndex", _I, _V)
_control_c = _declare("b3JointControlCommandInit2", _V, _V, _I, _I)
_desired_velocity = _declare("b3JointControlSetDesiredVelocity", _I, _V, _I, _D)
_maximum_force = _declare("b3JointControlSetMaximumForce", _I, _V, _I, _D)


class World:
    """N arms of a robot, fixed bases 2 m apart, inertias from the URDF, default motors
    off: the joints (PyBullet indices and velocity dofs, from a Python client of their
    own) and the set-up shared by both APIs."""

    def __init__(self, robot: str, n_arms: int) -> None:
        spec = get_robot(robot)
        self.gravity, self.urdf = spec.gravity, urdf_without_limits(spec.urdf)
        self.bases = [(2.0 * k, 0.0, 0.0) for k in range(n_arms)]
        lookup = p.connect(p.DIRECT)
        body = p.loadURDF(self.urdf, useFixedBase=True, physicsClientId=lookup)
        infos = {
            info[1].decode(): info
            for info in (
                p.getJointInfo(body, j, physicsClientId=lookup)
                for j in range(p.getNumJoints(body, physicsClientId=lookup))
            )
        }
        p.disconnect(lookup)
        self.joints = [infos[name][0] for name in spec.joint_names]
        self.dofs = np.array([infos[name][4] for name in spec.joint_names], dtype=np.intc)
        self.n_joints = len(self.joints)


class PythonWorld(World):
    """The world made and stepped through PyBullet's Python functions: the bare loop of
    ``bench.BarePyBullet`` / ``batched.BareBatch``."""

    def __init__(self, robot: str, n_arms: int, physics_dt: float) -> None:
        super().__init__(robot, n_arms)
        c = self.client = p.connect(p.DIRECT)
        p.setGravity(*self.gravity, physicsClientId=c)
        p.setTimeStep(physics_dt, physicsClientId=c)
        self.bodies = [
            p.loadURDF(
                self.urdf,
                basePosition=base,
                useFixedBase=True,
                flags=p.URDF_USE_INERTIA_FROM_FILE,
                physicsClientId=c,
            )
            for base in self.bases
        ]
        for body in self.bodies:
            p.setJointMotorControlArray(
                body,
                self.joints,
                p.VELOCITY_CONTROL,
                forces=[0.0] * self.n_joints,
                physicsClientId=c,
            )

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


class CompiledWorld(World):
    """The same world made through the C API (ctypes) and stepped by
    :func:`compiled_substeps`."""

    def __init__(self, robot: str, n_arms: int, physics_dt: float) -> None:
        super().__init__(robot, n_arms)
        self.handle = _connect()
        command = _physics_parameters(self.handle)
        _set_gravity(command, *self.gravity)
        _set_time_step(command, physics_dt)
        _submit_c(self.handle, command)
        bodies = []
        for base in self.bases:
            command = _load_urdf(self.handle, self.urdf.encode())
            _fixed_base(command, 1)
            _urdf_flags(command, p.URDF_USE_INERTIA_FROM_FILE)
            _start_position(command, *base)
            bodies.append(_body_index(_submit_c(self.handle, command)))
            command = _control_c(self.handle, bodies[-1], _VELOCITY_CONTROL)
            for dof in self.dofs:
                _desired_velocity(command, int(dof), 0.0)
                _maximum_force(command, int(dof), 0.0)
            _submit_c(self.handle, command)
        self.bodies = np.array(bodies, dtype=np.intc)
        self.joint_array = np.array(self.joints, dtype=np.intc)
        self.states = np.empty((n_arms, 2 * self.n_joints))
        self._sensor = np.empty(9)

    def step(self, torques: np.ndarray, n_substeps: int) -> None:
        """``n_substeps`` physics steps under ``torques`` (N, n), in one compiled call."""
        compiled_substeps(
            self.handle,
            self.bodies,
            self.dofs,
            self.joint_array,
            torques,
            n_substeps,
            self.states,
            self._sensor,
        )

    def joint_states(self) -> np.ndarray:
        return self.states.copy()

    def close(self) -> None:
        _disconnect(self.handle)


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
