"""PyBullet plant of N arms with elastic transmissions integrated next to each physics step.

All arms live in one PyBullet client (``p.DIRECT``, fixed bases apart, inertias from the
URDF, no PyBullet damping, pure torque control); each arm's trajectory is bit-identical
to the same arm alone, so a single env is the case N = 1. The motor side is integrated
for all arms at once with PyBullet's semi-implicit Euler, one substep at a time:

* model (1): tau_J = K (theta - q) + D (theta' - q') on the link joint,
  theta'' = B^-1 (tau - tau_J);
* model (2) (constant S): (M - S B^-1 S^T) q'' = tau_J - S B^-1 (tau - tau_J) - n - d,
  theta'' = B^-1 (tau - tau_J - S^T q''), and tau_J - S theta'' is applied to PyBullet;
* rigid joints: the motor torque acts on the link directly.

Link friction is applied explicitly from the state at the start of each substep. URDF
joint limits are not enforced by PyBullet; the env ends the episode when one is crossed.
"""

from __future__ import annotations

import contextlib
import operator
import os
import socket
import sys
from itertools import chain

import numpy as np
from numba import njit

from elastic_gym.envs import bullet_capi
from elastic_gym.envs.config import Integrator
from elastic_gym.envs.integration import RungeKutta
from elastic_gym.envs.plant import PAYLOAD_LINK, PlantArray, last_link, payload_urdf
from elastic_gym.envs.pybullet_quiet import pybullet as p
from elastic_gym.model import RobotModel, SerialChain
from elastic_gym.model.chain import (
    _dynamics_and_forces_kernel,
    forward_dynamics_kernel,
)
from elastic_gym.model.packed import Packed
from elastic_gym.robots.spec import RobotSpec
from elastic_gym.robots.urdf_tools import urdf_without_limits
from elastic_gym.validation import lookup

ARM_SPACING = 8.0  # m between the bases of neighbouring arms (well beyond any arm's reach)
X11_TIMEOUT = 1.0  # s to reach the X server before the PyBullet GUI is started
PAYLOAD_BYTES = PAYLOAD_LINK.encode()
_POSITION_VELOCITY = operator.itemgetter(0, 1)  # of a getJointStates entry


@njit(cache=True)
def _transmission_kernel(
    theta,
    dtheta,
    q,
    dq,
    tau,
    K,
    D,
    B_inv,
    viscous,
    coulomb_pos,
    coulomb_neg,
    smoothing,
    has_friction,
    has_coulomb,
    elastic,
    link,
    tau_j,
    ddtheta,
    dt,
):
    """Per arm k and joint j: tau_J = K (theta - q) + D (theta' - q'), the link torque
    tau_J - d(q') (rigid: tau - d(q')) and theta'' = B^-1 (tau - tau_J) of model (1);
    d(q') = F_v q' + c tanh(q' / smoothing), c = coulomb_pos or coulomb_neg by the sign.
    Every coefficient has a leading arm axis (arm k's own plant). ``dt`` > 0 (elastic
    arms): the motor side is then advanced in place as `_integrate_motors` does
    (each joint's theta'' depends only on its own state, read before it is advanced)."""
    N, n = q.shape
    for k in range(N):
        for j in range(n):
            friction = 0.0
            if has_friction:
                friction = viscous[k, j] * dq[k, j]
                if has_coulomb:
                    s = np.tanh(dq[k, j] / smoothing[k])
                    friction += (coulomb_pos[k, j] if s > 0.0 else coulomb_neg[k, j]) * s
            if elastic:
                torque = K[k, j] * (theta[k, j] - q[k, j]) + D[k, j] * (dtheta[k, j] - dq[k, j])
                tau_j[k, j] = torque
                link[k, j] = torque - friction
                ddtheta[k, j] = B_inv[k, j] * (tau[k, j] - torque)
                if dt > 0.0:
                    dtheta[k, j] = dtheta[k, j] + dt * ddtheta[k, j]
                    theta[k, j] = theta[k, j] + dt * dtheta[k, j]
            else:
                link[k, j] = tau[k, j] - friction


@njit(cache=True)
def _link_dynamics_kernel(theta, dtheta, q, dq, transmission, link_torque, *dynamics):
    """`_transmission_kernel` (its arguments after the state: ``transmission``; link
    torque into ``transmission[11]``), plus ``link_torque`` ((N, n), or (N, 0): none), then
    `_dynamics_and_forces_kernel` at that link torque
    (``dynamics``: its arguments after q, q', tau): the calls of
    [`ArmSimulator.accelerations`][elastic_gym.envs.simulator.ArmSimulator.accelerations] and the
    chain in one dispatch."""
    _transmission_kernel(theta, dtheta, q, dq, *transmission)
    link = transmission[11]
    if link_torque.shape[1]:
        for k in range(link.shape[0]):
            for j in range(link.shape[1]):
                link[k, j] += link_torque[k, j]
    _dynamics_and_forces_kernel(q, dq, link, *dynamics)


@njit(cache=True)
def _substep_kernel(joint_states, tau, packed):
    """q and q' of every arm from PyBullet's flat joint states (q, q' per joint, arm by arm;
    empty: the state is current), in place, then `_transmission_kernel` at the motor
    torques ``tau``: one dispatch per substep. ``packed``: a
    `Packed` of (theta, theta', q, q', the kernel's
    arguments after tau, an (N, 0) array: no link torque)."""
    theta, dtheta, q, dq, transmission, _ = packed.values
    _unpack_joint_states(joint_states, q, dq)
    _transmission_kernel(theta, dtheta, q, dq, tau, *transmission)


@njit(cache=True, inline="always")
def _is_coupled(coupling):
    """Whether ``coupling`` (`_coupled_link_torque`'s pack) is model (2)'s: S (N, n, n),
    not the (N, 0, 0) of model (1) and rigid arms."""
    return coupling.values[0].shape[1] > 0


@njit(cache=True)
def _period_kernel(slot, world, n_substeps, tau, link_torque, packed, coupling, states):
    """``n_substeps`` physics steps through PyBullet's C API (``slot``: the client's
    handle, see `client_slot`), each under the link torques of the motor torques ``tau``
    at the state the last one read, plus ``link_torque`` ((N, n), or (N, 0): none; one
    type, so one compiled signature): the loop of
    [`ArmSimulator.step`][elastic_gym.envs.simulator.ArmSimulator.step] in one dispatch.
    Model (1) and rigid arms (``coupling``'s matrices (N, 0, 0): the same signature as
    model (2)'s, compiled once): `_transmission_kernel`, the motors advanced before the
    physics step; model (2): `_coupled_link_torque`, the motors advanced after it.
    ``world``: (bodies, velocity indices (N, n), joint indices, sensor buffer);
    ``packed``: as `_substep_kernel`'s; ``states``: the flat joint states buffer. Returns
    a `bullet_capi` code."""
    handle = slot[0]
    if handle == 0:
        return bullet_capi.DISCONNECTED
    theta, dtheta, q, dq, transmission, no_link_torque = packed.values
    for substep in range(n_substeps):
        if substep > 0:
            _unpack_joint_states(states, q, dq)
        if not _is_coupled(coupling):
            _transmission_kernel(theta, dtheta, q, dq, tau, *transmission)
            code = bullet_capi.substep(handle, world, transmission[10], link_torque, states)
        else:
            link_tau = _coupled_link_torque(
                theta, dtheta, q, dq, tau, link_torque, transmission, coupling
            )
            code = bullet_capi.substep(handle, world, link_tau, no_link_torque, states)
            _integrate_motors(theta, dtheta, transmission[12], transmission[13])
        if code != bullet_capi.OK:
            return code
    _unpack_joint_states(states, q, dq)
    return bullet_capi.OK


@njit(cache=True)
def _rowwise_matvec_into(A, X, out):
    """[`rowwise_matvec`][elastic_gym.envs.simulator.rowwise_matvec] (A (N, n, n), X (N, n)) into
    ``out``, summed in its order."""
    N, n = X.shape
    for k in range(N):
        for i in range(n):
            total = X[k, 0] * A[k, i, 0]
            for j in range(1, n):
                total = total + X[k, j] * A[k, i, j]
            out[k, i] = total


@njit(cache=True)
def _coupled_link_torque(theta, dtheta, q, dq, tau, link_torque, transmission, coupling):
    """Model (2) at the current state, as
    [`ArmSimulator.accelerations`][elastic_gym.envs.simulator.ArmSimulator.accelerations] computes
    it
    (bit for bit): tau_J, theta'' into the transmission buffers (``transmission``: the
    transmission kernel's arguments after tau, its time step not used), q'' into
    ``coupling``'s, the link torque tau_J - d(q') (+ ``link_torque``: (N, n), or (N, 0):
    none) - S theta'' returned. ``coupling``: a `Packed` of (S, S B^-1,
    S^T, -S B^-1 S^T, the chain's forward dynamics arguments, four (N, n) buffers, the
    last q'')."""
    K, D, B_inv, viscous, c_pos, c_neg, smoothing, friction, coulomb = transmission[:9]
    # elastic: True for model (2), passed on as the flag (a literal True would compile a
    # second signature of the transmission kernel)
    elastic, link, tau_j, ddtheta = transmission[9:13]
    S, SBinv, ST, schur, dynamics, relative, product, rhs, ddq = coupling.values
    _transmission_kernel(
        theta, dtheta, q, dq, tau, K, D, B_inv, viscous, c_pos, c_neg, smoothing, friction,
        coulomb, elastic, link, tau_j, ddtheta, 0.0,
    )  # fmt: skip
    N, n = q.shape
    added = link_torque.shape[1] > 0
    for k in range(N):
        for j in range(n):
            if added:
                link[k, j] += link_torque[k, j]
            relative[k, j] = tau[k, j] - tau_j[k, j]
    _rowwise_matvec_into(SBinv, relative, product)
    for k in range(N):
        for j in range(n):
            rhs[k, j] = link[k, j] - product[k, j]
    forward_dynamics_kernel(q, dq, rhs, schur, ddq, dynamics)
    _rowwise_matvec_into(ST, ddq, product)
    for k in range(N):
        for j in range(n):
            ddtheta[k, j] = B_inv[k, j] * (relative[k, j] - product[k, j])
    _rowwise_matvec_into(S, ddtheta, product)
    for k in range(N):
        for j in range(n):
            rhs[k, j] = link[k, j] - product[k, j]
    return rhs


@njit(cache=True)
def _unpack_joint_states(joint_states, q, dq):
    """q[k, j], q'[k, j] = joint_states[2 (k n + j)], joint_states[2 (k n + j) + 1] (none
    when ``joint_states`` is empty)."""
    if joint_states.shape[0] == 0:
        return
    N, n = q.shape
    for k in range(N):
        for j in range(n):
            q[k, j] = joint_states[2 * (k * n + j)]
            dq[k, j] = joint_states[2 * (k * n + j) + 1]


@njit(cache=True)
def _integrate_motors(theta, dtheta, ddtheta, dt):
    """Semi-implicit Euler of the motor side, in place: theta' += dt theta'', theta += dt theta'."""
    N, n = theta.shape
    for k in range(N):
        for j in range(n):
            dtheta[k, j] = dtheta[k, j] + dt * ddtheta[k, j]
            theta[k, j] = theta[k, j] + dt * dtheta[k, j]


def rowwise_matvec(A: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(A_k @ x_k for each row x_k of X and matrix A_k of A (N, n, n)), summed in a fixed
    order: bit-identical per row whatever the number of rows (a BLAS call may change its
    summation with the shape)."""
    out = X[:, :1] * A[:, :, 0]
    for j in range(1, A.shape[2]):
        out = out + X[:, j : j + 1] * A[:, :, j]
    return out


def display_problem() -> str | None:
    """Why no X server answers at $DISPLAY (Linux), or None when one does.

    ``p.connect(p.GUI)`` without a reachable X server terminates the whole process,
    so the GUI is only started after a successful connection to the display.
    """
    if not sys.platform.startswith("linux"):
        return None
    display = os.environ.get("DISPLAY")
    if not display:
        return "DISPLAY is not set"
    host, _, rest = display.rpartition(":")
    number = rest.split(".")[0]
    if not number.isdigit():
        return f"cannot parse DISPLAY={display!r}"
    try:
        if host in ("", "unix"):
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
                sock.settimeout(X11_TIMEOUT)
                sock.connect(f"/tmp/.X11-unix/X{number}")
        else:
            socket.create_connection((host, 6000 + int(number)), timeout=X11_TIMEOUT).close()
    except OSError as exc:
        return f"no X server answers at DISPLAY={display!r} ({exc})"
    return None


class ArmSimulator:
    """One PyBullet client holding ``n_arms`` copies of an arm, plus their motor states.

    Args:
        spec: the robot.
        plant: the exact model of the simulated plant (same URDF and the same parameter
            scaling), or a `PlantArray` of one plant per
            arm; its [`SerialChain`][elastic_gym.model.SerialChain] gives model (2)'s q'' and
            the true q''.
        physics_dt: physics step (s).
        n_arms: number of arms.
        gui: connect with ``p.GUI`` instead of ``p.DIRECT`` (render_mode="human").
        payload_positions: per arm, None or the point (last link's frame) of the arm's
            payload link (`payload_urdf`); its mass is set
            with [`set_payload_mass`][elastic_gym.envs.simulator.ArmSimulator.set_payload_mass].
        integrator: `"pybullet"` (PyBullet's step at `physics_dt`, the transmission
            beside it) or `"rk4"` (the compiled RK4 of the whole state over a control
            period, `physics_dt` its largest substep; PyBullet's joints are set to the
            state when a pose is read or a frame rendered, see
            [`integration`][elastic_gym.envs.integration]).
        substeps: physics steps per control period (RK4: its fewest substeps).

    State arrays have a leading arm axis: ``q``, ``dq``, ``theta``, ``dtheta`` (N, n).

    Where PyBullet's C API can be reached (`bullet_capi`), a control
    period's substeps run in one compiled call (`_period_kernel`); otherwise
    `step` does the same work bit for bit through PyBullet's Python functions.
    """

    def __init__(
        self,
        spec: RobotSpec,
        plant: RobotModel | PlantArray,
        physics_dt: float,
        n_arms: int = 1,
        gui: bool = False,
        payload_positions: list | None = None,
        integrator: Integrator = "pybullet",
        substeps: int = 1,
    ):
        self.spec = spec
        self.plants = plant if isinstance(plant, PlantArray) else PlantArray([plant] * n_arms)
        self.n = n = spec.n_joints
        self.n_arms = n_arms
        self.physics_dt = float(physics_dt)
        problem = display_problem() if gui else None
        self.client = -1 if problem else p.connect(p.GUI if gui else p.DIRECT)
        if gui and self.client < 0:
            why = problem or "the PyBullet GUI did not start"
            raise RuntimeError(f"render_mode='human' needs a display: {why}")
        self._connected = True
        c = self.client
        p.resetSimulation(physicsClientId=c)
        p.setGravity(*spec.gravity, physicsClientId=c)
        p.setTimeStep(self.physics_dt, physicsClientId=c)
        p.setPhysicsEngineParameter(numSubSteps=0, physicsClientId=c)
        urdf = urdf_without_limits(spec.urdf)
        positions = payload_positions or [None] * n_arms
        self.base_positions = self._grid(n_arms)
        self.bodies = [
            p.loadURDF(
                urdf if at is None else payload_urdf(urdf, last_link(spec), tuple(at)),
                basePosition=base.tolist(),
                useFixedBase=True,
                flags=p.URDF_USE_INERTIA_FROM_FILE,
                physicsClientId=c,
            )
            for base, at in zip(self.base_positions, positions, strict=True)
        ]
        self.payload_links = [
            None if at is None else self._link_index(body, PAYLOAD_LINK)
            for body, at in zip(self.bodies, positions, strict=True)
        ]
        first = self.bodies[0]
        name_to_index = {
            p.getJointInfo(first, j, physicsClientId=c)[1].decode(): j
            for j in range(p.getNumJoints(first, physicsClientId=c))
        }
        self.joint_indices = [
            lookup(name_to_index, name, f"joint of {spec.urdf}") for name in spec.joint_names
        ]
        self._urdf_dynamics: list[dict] = []  # per arm: link -> (joint, mass, inertia)
        for arm, body in enumerate(self.bodies):
            self._configure_dynamics(body)
            self.set_link_scaling(arm, self.plants.models[arm].scaling)

        shape = (n_arms, n)
        # the state, written in place (a rigid arm's theta is its q)
        self.q, self.dq = np.zeros(shape), np.zeros(shape)
        # a substep's link torque, tau_J and theta''
        self._buffers = (np.empty(shape), np.empty(shape), np.empty(shape))
        self._elastic = spec.elastic
        self.theta, self.dtheta = (
            (np.zeros(shape), np.zeros(shape)) if self._elastic else (self.q, self.dq)
        )
        self._no_states = np.empty(0)
        self.no_link_torque = np.zeros((n_arms, 0))  # the kernels' link torque "none"
        self._packed: tuple | None = None  # see _substep_arguments
        self._count = 2 * n_arms * n  # numbers read from PyBullet per substep
        # PyBullet's C API (None: the Python functions step the world)
        self._slot = None if gui else bullet_capi.client_slot(c)
        self._states = np.empty(self._count)
        self._world = (
            None
            if self._slot is None
            else bullet_capi.world_arrays(c, self.bodies, self.joint_indices)
        )
        self.integrator = integrator
        self.gui = gui
        self.rk4 = (
            RungeKutta(
                self.plants, (self.theta, self.dtheta, self.q, self.dq), spec.elastic, substeps
            )
            if integrator == "rk4"
            else None
        )
        self.control_period = substeps * self.physics_dt  # the RK4's period

    @property
    def chain(self) -> SerialChain:
        """The plants' chain, stacked per arm."""
        return self.plants.chain

    @staticmethod
    def _grid(n_arms: int) -> np.ndarray:
        """Base positions of the arms: a square grid in the horizontal plane."""
        side = int(np.ceil(np.sqrt(n_arms)))
        index = np.arange(n_arms)
        return np.stack(
            [ARM_SPACING * (index % side), ARM_SPACING * (index // side), np.zeros(n_arms)], axis=1
        )

    def _link_index(self, body: int, name: str) -> int:
        """The PyBullet index of the URDF link ``name`` (``ValueError`` listing the links)."""
        c = self.client
        links = {
            p.getJointInfo(body, j, physicsClientId=c)[12].decode(): j
            for j in range(p.getNumJoints(body, physicsClientId=c))
        }
        return lookup(links, name, "URDF link")

    # ------------------------------------------------------------------ setup
    def _configure_dynamics(self, body: int) -> None:
        """Zero all damping, disable default motors, remember the URDF's link inertias."""
        c = self.client
        n_links = p.getNumJoints(body, physicsClientId=c)
        links = {}
        for link, j in self._owning_joint(body, n_links).items():
            info = p.getDynamicsInfo(body, link, physicsClientId=c)
            links[link] = (j, info[0], np.asarray(info[2]))
        self._urdf_dynamics.append(links)
        for link in range(-1, n_links):
            # One property per call: PyBullet 3.2.7 silently drops jointDamping when it is
            # passed together with other properties (measured: URDF damping stayed active).
            for prop in (
                {"linearDamping": 0.0},
                {"angularDamping": 0.0},
                {"jointDamping": 0.0},
                {"maxJointVelocity": 1e4},
            ):
                p.changeDynamics(body, link, **prop, physicsClientId=c)
        for j in range(n_links):
            p.setJointMotorControl2(
                body, j, p.VELOCITY_CONTROL, targetVelocity=0.0, force=0.0, physicsClientId=c
            )

    def set_link_scaling(self, arm: int, scaling) -> None:
        """Masses and inertias of arm ``arm``'s links: the URDF's scaled by ``scaling``
        (a [`ParameterScaling`][elastic_gym.model.ParameterScaling]); only links whose value changes
        are touched, so a body's dynamics depend on the scaling alone."""
        c, body = self.client, self.bodies[arm]
        mass_scale = scaling.per_joint("link_mass", self.n)
        inertia_scale = scaling.per_joint("link_inertia", self.n)
        for link, (j, mass, inertia) in self._urdf_dynamics[arm].items():
            target = mass * mass_scale[j]
            diagonal = inertia * mass_scale[j] * inertia_scale[j]
            info = p.getDynamicsInfo(body, link, physicsClientId=c)
            if info[0] != target or not np.array_equal(info[2], diagonal):
                p.changeDynamics(
                    body,
                    link,
                    mass=target,
                    localInertiaDiagonal=diagonal.tolist(),
                    physicsClientId=c,
                )

    def set_payload_mass(self, arm: int, mass: float) -> None:
        """The mass (kg) of arm ``arm``'s payload link (a point mass)."""
        link = self.payload_links[arm]
        if link is None:
            raise ValueError(f"arm {arm} was built without a payload link")
        p.changeDynamics(  # a point mass: no rotational inertia (PyBullet would scale its own)
            self.bodies[arm],
            link,
            mass=float(mass),
            localInertiaDiagonal=[0.0, 0.0, 0.0],
            physicsClientId=self.client,
        )

    def _owning_joint(self, body: int, n_links: int) -> dict[int, int]:
        """Map each PyBullet link to the actuated joint that moves it (fixed children inherit)."""
        c = self.client
        actuated = {idx: k for k, idx in enumerate(self.joint_indices)}
        owner: dict[int, int] = {}
        for link in range(n_links):
            j = link
            while j >= 0 and j not in actuated:
                j = p.getJointInfo(body, j, physicsClientId=c)[16]
            if j >= 0 and p.getJointInfo(body, link, physicsClientId=c)[12] != PAYLOAD_BYTES:
                owner[link] = actuated[j]
        return owner

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> np.ndarray:
        """x = (theta, q, theta', q') per arm, (N, 4n) (rigid arms: theta = q)."""
        return np.concatenate([self.theta, self.q, self.dtheta, self.dq], axis=1)

    def reset_state(
        self, arms: np.ndarray, q: np.ndarray, dq: np.ndarray, theta: np.ndarray, dtheta: np.ndarray
    ) -> None:
        """Set the state of the given arms (rows of q, dq, theta, dtheta, in ``arms`` order)."""
        c = self.client
        for row, arm in enumerate(arms):
            body = self.bodies[arm]
            for k, j in enumerate(self.joint_indices):
                p.resetJointState(body, j, float(q[row, k]), float(dq[row, k]), physicsClientId=c)
        self.q[arms], self.dq[arms] = q, dq
        if self._elastic:
            self.theta[arms], self.dtheta[arms] = theta, dtheta
        else:
            self.theta[arms], self.dtheta[arms] = q, dq
        if self.rk4 is not None:
            self.rk4.reset(arms)

    def sync_world(self) -> None:
        """With the RK4, set PyBullet's joints to the state (q, q'): before a link pose is
        read or a frame rendered (after every period in a GUI world); PyBullet's own step
        keeps them current."""
        if self.rk4 is None:
            return
        c = self.client
        for arm, body in enumerate(self.bodies):
            for k, j in enumerate(self.joint_indices):
                q, dq = float(self.q[arm, k]), float(self.dq[arm, k])
                p.resetJointState(body, j, q, dq, physicsClientId=c)

    def _joint_states(self) -> np.ndarray:
        """PyBullet's q and q' of every joint, flat (q, q' per joint, arm by arm)."""
        c, joints, get = self.client, self.joint_indices, p.getJointStates
        if self.n_arms == 1:
            states = get(self.bodies[0], joints, physicsClientId=c)
        else:
            states = chain.from_iterable([get(b, joints, physicsClientId=c) for b in self.bodies])
        return np.fromiter(chain.from_iterable(map(_POSITION_VELOCITY, states)), float, self._count)

    # ------------------------------------------------------------------ stepping
    def accelerations(
        self, tau: np.ndarray, link_torque: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """(link torque applied to PyBullet, theta'', q'' or None) under motor torque tau
        and an external link-side torque ``link_torque`` (N, n) (e.g. a torque pulse).

        q'' is computed only where it is needed for the link torque (model (2)).
        """
        plants = self.plants
        if not self._elastic and not plants.has_friction:
            return (tau if link_torque is None else tau + link_torque), None, None
        shape = self.q.shape
        link, tau_j, ddtheta = np.empty(shape), np.empty(shape), np.empty(shape)
        return self._transmission(tau, link_torque, link, tau_j, ddtheta, 0.0)

    def _substep_arguments(self) -> tuple[Packed, Packed]:
        """`_substep_kernel`'s packed arguments (the state, the plants' transmission
        constants, the buffers, the physics step, no link torque) and
        `_coupled_link_torque`'s (without model (2): S and the other matrices
        (N, 0, 0)), packed again when the plants change."""
        plants = self.plants
        transmission = plants.transmission
        if self._packed is None or self._packed[0] is not transmission:
            constants = self._transmission_arguments(self._elastic, *self._buffers, self.physics_dt)
            state = (self.theta, self.dtheta, self.q, self.dq)
            if plants.has_coupling:
                matrices = (plants.S, plants.SBinv, plants.ST, plants.schur_inertia)
            else:  # of the same types, so that model (1) compiles the same signature
                matrices = (np.empty((self.q.shape[0], 0, 0)),) * 4
            buffers = tuple(np.empty(self.q.shape) for _ in range(4))
            dynamics = plants.chain.forward_dynamics_arguments()
            coupling = Packed((*matrices, dynamics, *buffers))
            substep = Packed((*state, constants, self.no_link_torque))
            self._packed = (transmission, substep, coupling)
        return self._packed[1], self._packed[2]

    def period_arguments(self) -> tuple | None:
        """The physics of a control period for compiled callers (the batch's
        `control_period_kernel`): (`_period_kernel`'s arguments but the substep count, the
        torques and the link torque, None) or (None, the RK4's arguments after the
        torques), or None where the period cannot run in one call (PyBullet's C API out of
        reach; a GUI world)."""
        if self.rk4 is not None:
            if self.gui:
                return None
            return None, self.rk4.period_arguments(self.control_period)
        if self._slot is None:
            return None
        packed, coupling = self._substep_arguments()
        return (self._slot, self._world, packed, coupling, self._states), None

    def _link_array(self, link_torque: np.ndarray | None) -> np.ndarray:
        """The kernels' link torque: C-contiguous float64 (N, n), or (N, 0) for none."""
        if link_torque is None:
            return self.no_link_torque
        return np.ascontiguousarray(link_torque, dtype=np.float64)

    def coupling_arguments(self) -> Packed:
        """`_coupled_link_torque`'s ``coupling`` (its matrices (N, 0, 0) without model
        (2)), for compiled callers (the batch's end of a control period)."""
        return self._substep_arguments()[1]

    def _transmission_arguments(self, elastic: bool, link, tau_j, ddtheta, dt: float):
        """The arguments of the transmission kernel after the state (q, theta and rates)
        and the motor torques."""
        return (*self.plants.transmission, elastic, link, tau_j, ddtheta, dt)

    def _transmission(self, tau, link_torque, link, tau_j, ddtheta, dt: float):
        """`accelerations` into the given arrays (``dt``: see the kernel)."""
        plants = self.plants
        _transmission_kernel(
            self.theta,
            self.dtheta,
            self.q,
            self.dq,
            tau,
            *self._transmission_arguments(self._elastic, link, tau_j, ddtheta, dt),
        )
        if link_torque is not None:
            link += link_torque
        if not self._elastic:
            return link, None, None
        if not plants.has_coupling:
            return link, ddtheta, None
        rhs = link - rowwise_matvec(plants.SBinv, tau - tau_j)
        ddq = plants.chain.forward_dynamics(self.q, self.dq, rhs, plants.schur_inertia)
        ddtheta = plants.B_inv * (tau - tau_j - rowwise_matvec(plants.ST, ddq))
        return link - rowwise_matvec(plants.S, ddtheta), ddtheta, ddq

    def step(self, tau: np.ndarray, n_substeps: int, link_torque: np.ndarray | None = None) -> None:
        """Advance ``n_substeps`` physics steps holding the motor torques ``tau`` (N, n) and
        the external link-side torques ``link_torque`` (N, n, default none); with the RK4,
        one control period of ``n_substeps * physics_dt`` (its substeps its own)."""
        tau = np.ascontiguousarray(tau, dtype=np.float64)
        if self.rk4 is not None:
            self.rk4.step(tau, n_substeps * self.physics_dt, link_torque)
            if self.gui:
                self.sync_world()
            return
        packed, coupling = self._substep_arguments()
        if self._slot is not None:
            code = _period_kernel(
                self._slot, self._world, n_substeps, tau, self._link_array(link_torque),
                packed, coupling, self._states,
            )  # fmt: skip
            bullet_capi.raise_for(code)
            return
        # the same loop through PyBullet's Python functions: without model (2)'s coupling
        # the transmission kernel advances the motors (they do not depend on PyBullet's
        # step), with it they are advanced after PyBullet's step
        link = self._buffers[0]
        coupled = self.plants.has_coupling
        states = self._no_states  # PyBullet's joint states not yet in q, q'
        for _ in range(n_substeps):
            if not coupled:  # the last substep's joint states and the transmission
                _substep_kernel(states, tau, packed)
                link_tau = link if link_torque is None else link + link_torque
            else:
                _unpack_joint_states(states, self.q, self.dq)
                link_tau, ddtheta, _ = self.accelerations(tau, link_torque)
            states = self._python_substep(link_tau)
            if coupled:
                _integrate_motors(self.theta, self.dtheta, ddtheta, self.physics_dt)
        _unpack_joint_states(states, self.q, self.dq)

    def _python_substep(self, link_tau: np.ndarray) -> np.ndarray:
        """One physics step under the link torques ``link_tau`` (N, n) through PyBullet's
        Python functions: the joint states read after it (as `_joint_states`)."""
        c, joints, bodies = self.client, self.joint_indices, self.bodies
        control, set_torques = p.TORQUE_CONTROL, p.setJointMotorControlArray
        if len(bodies) == 1:
            set_torques(bodies[0], joints, control, forces=link_tau[0].tolist(), physicsClientId=c)
        else:
            for body, forces in zip(bodies, link_tau.tolist(), strict=True):
                set_torques(body, joints, control, forces=forces, physicsClientId=c)
        p.stepSimulation(physicsClientId=c)
        return self._joint_states()

    def link_acceleration(
        self, tau: np.ndarray, link_torque: np.ndarray | None = None
    ) -> np.ndarray:
        """True q'' (N, n) at the current state under motor torques tau and external link
        torques ``link_torque`` (plant models, exact)."""
        link_tau, _, ddq = self.accelerations(tau, link_torque)
        if ddq is not None:
            return ddq
        return self.plants.chain.forward_dynamics(self.q, self.dq, link_tau)

    def link_acceleration_and_forces(
        self, tau: np.ndarray, link_torque: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """(q'' as [`link_acceleration`][elastic_gym.envs.simulator.ArmSimulator.link_acceleration],
        the noise-free accelerometer readings of eq. (9) at it, (N, 3 n_sensors), or None for
        model (2), whose q'' comes with its torques):
        q'' and the readings in one compiled call where they can be."""
        plants = self.plants
        if plants.has_coupling or not (self._elastic or plants.has_friction):
            link_tau, _, ddq = self.accelerations(tau, link_torque)
            if ddq is not None:
                return ddq, None
            return plants.chain.forward_dynamics_and_forces(self.q, self.dq, link_tau)
        shape = self.q.shape  # model (1) or friction: the transmission kernel, as above
        ddq, forces = np.empty(shape), np.empty((shape[0], 3 * plants.chain.n_sensors))
        transmission = (
            np.ascontiguousarray(tau, dtype=np.float64),
            *self._transmission_arguments(
                self._elastic, np.empty(shape), np.empty(shape), np.empty(shape), 0.0
            ),
        )
        _link_dynamics_kernel(
            self.theta,
            self.dtheta,
            self.q,
            self.dq,
            transmission,
            self._link_array(link_torque),
            *plants.chain.dynamics_and_forces_arguments(ddq, forces),
        )
        return ddq, forces

    def link_pose(self, link_name: str, arm: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Position (from the arm's base) and rotation of a URDF link frame, from PyBullet."""
        self.sync_world()
        c, body = self.client, self.bodies[arm]
        j = self._link_index(body, link_name)
        state = p.getLinkState(body, j, computeForwardKinematics=1, physicsClientId=c)
        rot = np.asarray(p.getMatrixFromQuaternion(state[5])).reshape(3, 3)
        return np.asarray(state[4]) - self.base_positions[arm], rot

    # ------------------------------------------------------------------ rendering
    def render(self, arm: int = 0, width: int = 480, height: int = 360) -> np.ndarray:
        """RGB image (H, W, 3) of one arm from the offscreen tiny renderer."""
        self.sync_world()
        target, distance, yaw, pitch = self.spec.camera
        c = self.client
        view = p.computeViewMatrixFromYawPitchRoll(
            (np.asarray(target) + self.base_positions[arm]).tolist(),
            distance,
            yaw,
            pitch,
            0.0,
            2,
            physicsClientId=c,
        )
        proj = p.computeProjectionMatrixFOV(60.0, width / height, 0.05, 50.0, physicsClientId=c)
        _, _, rgba, _, _ = p.getCameraImage(
            width, height, view, proj, renderer=p.ER_TINY_RENDERER, physicsClientId=c
        )
        return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[:, :, :3]

    @property
    def connected(self) -> bool:
        return self._connected

    def close(self) -> None:
        if self._connected:
            self._connected = False
            with contextlib.suppress(p.error):
                p.disconnect(physicsClientId=self.client)

    def __del__(self) -> None:  # pragma: no cover - best effort cleanup
        with contextlib.suppress(Exception):
            self.close()
