"""Nominal robot model: pinocchio rigid-body dynamics of the URDF plus the elastic joints.

The models of De Luca, Schroeder & Thuemmel (ICRA 2007), with the joint torque
tau_J = K (theta - q) + D (theta' - q') and the state x = (theta, q, theta', q') of eq. (3):

* model (1):  M(q) q'' + C(q, q') q' + g(q) + d(q') = tau_J,   B theta'' + tau_J = tau;
* model (2):  M(q) q'' + S theta'' + C q' + g + d = tau_J,   S^T q'' + B theta'' + tau_J = tau.

Accelerometer maps, eqs. (8)-(10): a sensor's specific force in its own frame is
T_A(q) q'' + W_A(q, q'), T_A = R_WS^T J_lin(q), W_A = R_WS^T (Jdot q' - g_W). Observers and
controllers get a `RobotModel` from ``env.unwrapped.model`` and never touch the
simulator; [`RobotModel.perturbed`][elastic_gym.model.robot_model.RobotModel.perturbed] gives a copy
with parameter errors.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pinocchio as pin

from elastic_gym.model.chain import SerialChain
from elastic_gym.robots.spec import AccelerometerMount, LinkFriction, RobotSpec
from elastic_gym.robots.urdf_tools import urdf_text_for_pinocchio
from elastic_gym.validation import (
    ConfigModel,
    NonNegativeFinite,
    NonNegativeNumbers,
    PositiveNumbers,
    per_joint_values,
)


class ParameterScaling(ConfigModel):
    """Multiplicative parameter changes (1.0 = nominal).

    Used for the simulated plant (``env`` kwarg ``plant_scaling``) and for model copies
    with errors ([`RobotModel.perturbed`][elastic_gym.model.robot_model.RobotModel.perturbed]).
    ``link_mass`` scales the mass and rotational inertia of every link together (a
    uniformly denser link, centre of mass unchanged); ``link_inertia`` scales only the
    rotational inertia. Scalars or one value per joint (the links moved by that joint),
    each > 0 (``damping`` and ``friction`` >= 0).
    """

    link_mass: PositiveNumbers = 1.0
    link_inertia: PositiveNumbers = 1.0
    stiffness: PositiveNumbers = 1.0
    motor_inertia: PositiveNumbers = 1.0
    damping: NonNegativeNumbers = 1.0  # D >= 0 and d(q') >= 0 are physical
    friction: NonNegativeFinite = 1.0

    def per_joint(self, name: str, n: int) -> np.ndarray:
        """The factor ``name`` for each of ``n`` joints (a scalar is repeated)."""
        return per_joint_values(getattr(self, name), n, f"parameter scaling {name!r}")

    @property
    def is_nominal(self) -> bool:
        return all(np.all(np.asarray(getattr(self, f)) == 1.0) for f in type(self).model_fields)


class RobotModel:
    """Pinocchio model of a `RobotSpec` with its elastic transmission.

    All arrays are float64. Methods are not thread-safe (one pinocchio ``Data``
    per instance); use [`copy`][elastic_gym.model.robot_model.RobotModel.copy] to give each user its
    own. ``added_friction``: link
    friction beyond the spec's (a simulated plant's unmodelled friction), added to the
    spec's friction after ``scaling``.
    """

    def __init__(
        self,
        spec: RobotSpec,
        scaling: ParameterScaling | dict | None = None,
        accelerometers: tuple[AccelerometerMount, ...] | None = None,
        added_friction: LinkFriction | None = None,
    ) -> None:
        self.spec = spec
        self.scaling = ParameterScaling.from_config(scaling)
        n = spec.n_joints
        self.n = n
        self.pin_model = pin.buildModelFromXML(urdf_text_for_pinocchio(spec.urdf))
        self.pin_model.gravity.linear = np.asarray(spec.gravity, dtype=float)
        names = tuple(self.pin_model.names[1:])
        if names != spec.joint_names or self.pin_model.nq != n or self.pin_model.nv != n:
            raise ValueError(
                f"URDF joints {names} (nq={self.pin_model.nq}) do not match spec joints "
                f"{spec.joint_names}"
            )
        self._apply_link_scaling()

        elastic = spec.elastic
        self.elastic = elastic
        self.K = self._vector(spec.stiffness, "stiffness") if elastic else np.zeros(n)
        self.B = self._vector(spec.motor_inertia, "motor_inertia") if elastic else np.zeros(n)
        self.D = self._vector(spec.damping, "damping") if elastic else np.zeros(n)
        self.S = (
            np.asarray(spec.coupling, dtype=float) * self.scaling.per_joint("motor_inertia", n)
            if spec.coupling is not None
            else np.zeros((n, n))
        )
        self.has_coupling = bool(np.any(self.S != 0.0))
        self.B_inv = np.where(self.B > 0.0, 1.0 / np.where(self.B > 0.0, self.B, 1.0), 0.0)
        own = spec.friction.scaled(self.scaling.friction) if spec.friction is not None else None
        self.added_friction = added_friction
        self.friction: LinkFriction | None = own.plus(added_friction) if own else added_friction
        self.torque_limit = np.asarray(spec.torque_limit, dtype=float)
        self.gravity_vector = np.asarray(spec.gravity, dtype=float)

        mounts = spec.accelerometers if accelerometers is None else tuple(accelerometers)
        self.accelerometers: tuple[AccelerometerMount, ...] = tuple(
            AccelerometerMount.from_config(m) for m in mounts
        )
        self.sensor_frame_ids = [self._add_sensor_frame(m) for m in self.accelerometers]
        self.data = self.pin_model.createData()
        SBinv = self.S * self.B_inv
        self._SBinv, self._SBinvST = SBinv, SBinv @ self.S.T  # model (2) constants
        self._lower = np.tril_indices(n, -1)
        self._zero_acceleration = np.zeros(n)
        self._symmetric_outputs = self._pinocchio_fills_lower_triangles()
        self._chain: SerialChain | None = None

    # ------------------------------------------------------------------ setup
    def _vector(self, values: tuple[float, ...] | None, scale_name: str) -> np.ndarray:
        return np.asarray(values, dtype=float) * self.scaling.per_joint(scale_name, self.n)

    def _apply_link_scaling(self) -> None:
        mass = self.scaling.per_joint("link_mass", self.n)
        inertia = self.scaling.per_joint("link_inertia", self.n)
        for j in range(1, self.pin_model.njoints):
            body = self.pin_model.inertias[j]
            s_m, s_i = mass[j - 1], inertia[j - 1]
            self.pin_model.inertias[j] = pin.Inertia(
                body.mass * s_m, body.lever.copy(), body.inertia * (s_m * s_i)
            )

    def _add_sensor_frame(self, mount: AccelerometerMount) -> int:
        if not self.pin_model.existBodyName(mount.link):
            links = [f.name for f in self.pin_model.frames if f.type == pin.FrameType.BODY]
            raise ValueError(f"accelerometer link {mount.link!r} not in the URDF; links: {links}")
        body_id = self.pin_model.getBodyId(mount.link)
        body = self.pin_model.frames[body_id]
        local = pin.SE3(pin.rpy.rpyToMatrix(*mount.rpy), np.asarray(mount.position))
        frame = pin.Frame(
            mount.name, body.parentJoint, body_id, body.placement * local, pin.FrameType.OP_FRAME
        )
        return self.pin_model.addFrame(frame)

    def _pinocchio_fills_lower_triangles(self) -> bool:
        """Whether crba/RNEA/ABA derivatives return full symmetric matrices (recent pinocchio)
        or only their upper triangles (older releases), checked once at a generic q."""
        q = np.linspace(0.3, 0.9, self.n)
        M = pin.crba(self.pin_model, self.data, q)
        Minv = pin.computeABADerivatives(self.pin_model, self.data, q, q, q)[2]
        return bool(np.array_equal(M, M.T) and np.array_equal(Minv, Minv.T))

    def _symmetric(self, matrix: np.ndarray) -> np.ndarray:
        """A copy of a pinocchio symmetric-matrix output with its lower triangle filled."""
        matrix = matrix.copy()
        if not self._symmetric_outputs:
            matrix[self._lower] = matrix.T[self._lower]
        return matrix

    def copy(self) -> RobotModel:
        """Independent copy (own pinocchio Data)."""
        new = copy.copy(self)
        new.pin_model = self.pin_model.copy()
        new.data = new.pin_model.createData()
        new._chain = None
        return new

    @property
    def chain(self) -> SerialChain:
        """The same model for N arms at once (`SerialChain`), built on first use."""
        if self._chain is None:
            self._chain = SerialChain(self.pin_model, self.sensor_frame_ids)
        return self._chain

    def perturbed(self, scaling: ParameterScaling | dict | None = None, **kwargs) -> RobotModel:
        """A model of the same robot with parameter errors relative to this one.

        ``model.perturbed(link_mass=1.1)`` is the nominal model with +10 % link masses.
        Scalings compose multiplicatively with the scaling this model already has.
        """
        extra = ParameterScaling.from_config(scaling if scaling is not None else kwargs)
        n = self.n
        combined: dict[str, Any] = {}
        for name in ParameterScaling.model_fields:
            if name == "friction":
                combined[name] = self.scaling.friction * extra.friction
            else:
                combined[name] = tuple(
                    (self.scaling.per_joint(name, n) * extra.per_joint(name, n)).tolist()
                )
        friction = self.added_friction
        if friction is not None and extra.friction != 1.0:
            friction = friction.scaled(extra.friction)
        return RobotModel(self.spec, ParameterScaling(**combined), self.accelerometers, friction)

    # ------------------------------------------------------- rigid dynamics
    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """Link inertia matrix M(q) (symmetric, CRBA)."""
        return self._symmetric(pin.crba(self.pin_model, self.data, q))

    def coriolis_matrix(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """C(q, q') built from Christoffel symbols (M' - 2C skew-symmetric)."""
        return pin.computeCoriolisMatrix(self.pin_model, self.data, q, dq).copy()

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """Gravity torque g(q)."""
        return pin.computeGeneralizedGravity(self.pin_model, self.data, q).copy()

    def nonlinear_effects(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """n(q, q') = C(q, q') q' + g(q)."""
        return pin.nonLinearEffects(self.pin_model, self.data, q, dq).copy()

    def link_friction(self, dq: np.ndarray) -> np.ndarray:
        """Link-side friction d(q') (zero when the robot has none)."""
        return self.friction.torque(dq) if self.friction is not None else np.zeros(self.n)

    def rnea(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Inverse dynamics M q'' + C q' + g (without friction)."""
        return pin.rnea(self.pin_model, self.data, q, dq, ddq).copy()

    def rnea_derivatives(
        self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(d tau/d q, d tau/d q', M) of `rnea`."""
        dtau_dq, dtau_dv, M = pin.computeRNEADerivatives(self.pin_model, self.data, q, dq, ddq)
        return dtau_dq.copy(), dtau_dv.copy(), self._symmetric(M)

    def aba(self, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Forward dynamics q'' = M^-1 (tau - C q' - g) (without friction)."""
        return pin.aba(self.pin_model, self.data, q, dq, tau).copy()

    def aba_derivatives(
        self, q: np.ndarray, dq: np.ndarray, tau: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(d q''/d q, d q''/d q', M^-1) of
        [`aba`][elastic_gym.model.robot_model.RobotModel.aba]."""
        ddq_dq, ddq_dv, Minv = pin.computeABADerivatives(self.pin_model, self.data, q, dq, tau)
        return ddq_dq.copy(), ddq_dv.copy(), self._symmetric(Minv)

    def rigid_acceleration(self, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Rigid-arm forward dynamics with friction: M q'' + C q' + g + d(q') = tau."""
        return self.aba(q, dq, tau - self.link_friction(dq))

    # ----------------------------------------------------- elastic dynamics
    def joint_torque(
        self, theta: np.ndarray, q: np.ndarray, dtheta: np.ndarray, dq: np.ndarray
    ) -> np.ndarray:
        """Spring + damper torque tau_J = K (theta - q) + D (theta' - q')."""
        return self.K * (theta - q) + self.D * (dtheta - dq)

    def elastic_accelerations(
        self, x: np.ndarray, tau: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(theta'', q'') of model (1), or of model (2) when S != 0.

        Model (2) is solved through the Schur complement
        (M - S B^-1 S^T) q'' = tau_J - S B^-1 (tau - tau_J) - n - d,
        theta'' = B^-1 (tau - tau_J - S^T q'').
        """
        n = self.n
        theta, q, dtheta, dq = x[:n], x[n : 2 * n], x[2 * n : 3 * n], x[3 * n :]
        tau_j = self.joint_torque(theta, q, dtheta, dq)
        link_tau = tau_j - self.link_friction(dq)
        if not self.has_coupling:
            ddq = self.aba(q, dq, link_tau)
            return self.B_inv * (tau - tau_j), ddq
        schur = self.mass_matrix(q) - self._SBinvST
        nle = pin.nonLinearEffects(self.pin_model, self.data, q, dq)
        ddq = np.linalg.solve(schur, link_tau - self._SBinv @ (tau - tau_j) - nle)
        return self.B_inv * (tau - tau_j - self.S.T @ ddq), ddq

    def elastic_dynamics(self, x: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """State derivative x' = f(x) + G u of eq. (4) (or its model-(2) counterpart)."""
        n = self.n
        ddtheta, ddq = self.elastic_accelerations(x, tau)
        return np.concatenate([x[2 * n : 3 * n], x[3 * n :], ddtheta, ddq])

    def static_motor_position(self, q: np.ndarray) -> np.ndarray:
        """Motor position holding the links at rest at q: theta = q + K^-1 g(q)."""
        return q + self.gravity(q) / self.K

    def static_link_position(
        self,
        theta: np.ndarray,
        initial: np.ndarray | None = None,
        tolerance: float = 1e-12,
        max_iterations: int = 50,
    ) -> np.ndarray:
        """Link position of the arm at rest for motor position theta.

        Solves theta = q + K^-1 g(q) (the inverse of
        [`static_motor_position`][elastic_gym.model.robot_model.RobotModel.static_motor_position])
        by the fixed-point iteration q <- theta - K^-1 g(q), a contraction since |K^-1 dg/dq| << 1.
        This is how an observer initialises q from the motor encoders with only the gravity
        vector known (De Luca et al., end of Sec. IV). ``theta`` (and ``initial``) may also
        be (N, n) arrays of several arms; each row iterates until its own convergence, so a
        row's result does not depend on the others.
        """
        theta = np.asarray(theta, dtype=float)
        single = theta.ndim == 1
        theta = np.atleast_2d(theta)
        q = theta.copy() if initial is None else np.array(np.broadcast_to(initial, theta.shape))
        active = np.arange(len(theta))
        for _ in range(max_iterations):
            q_next = theta[active] - self.chain.gravity(q[active]) / self.K
            converged = np.max(np.abs(q_next - q[active]), axis=1) < tolerance
            q[active] = q_next
            active = active[~converged]
            if not len(active):
                break
        return q[0] if single else q

    def energy(
        self,
        q: np.ndarray,
        dq: np.ndarray,
        theta: np.ndarray | None = None,
        dtheta: np.ndarray | None = None,
    ) -> float:
        """Total energy: link kinetic + potential, motor kinetic (+ S coupling), springs."""
        M = self.mass_matrix(q)
        energy = 0.5 * dq @ M @ dq + pin.computePotentialEnergy(self.pin_model, self.data, q)
        if self.elastic and theta is not None and dtheta is not None:
            delta = theta - q
            energy += 0.5 * dtheta @ (self.B * dtheta) + dq @ self.S @ dtheta
            energy += 0.5 * delta @ (self.K * delta)
        return float(energy)

    def natural_frequencies(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Undamped vibration frequencies (rad/s) of the elastic arm linearized at rest at q.

        Returns ``(free, locked)``: ``free`` are the N elastic modes of the complete arm
        (generalized eigenvalues of the stiffness [[K, -K], [-K, K + dg/dq]] over the
        inertia [[B, S^T], [S, M(q)]], rigid-body modes dropped); ``locked`` are the
        link-side modes with the motors held still (eigenvalues of M^-1 (K + dg/dq)).
        """
        n = self.n
        M = self.mass_matrix(q)
        dg = pin.computeGeneralizedGravityDerivatives(self.pin_model, self.data, q)
        inertia = np.block([[np.diag(self.B), self.S.T], [self.S, M]])
        K = np.diag(self.K)
        stiffness = np.block([[K, -K], [-K, K + dg]])
        free = np.sqrt(np.abs(np.linalg.eigvals(np.linalg.solve(inertia, stiffness)).real))
        locked = np.sqrt(np.abs(np.linalg.eigvals(np.linalg.solve(M, K + dg)).real))
        return np.sort(free)[n:], np.sort(locked)

    # ---------------------------------------------------------- sensors
    @property
    def n_sensors(self) -> int:
        return len(self.sensor_frame_ids)

    def sensor_placements(self, q: np.ndarray) -> list[pin.SE3]:
        """World placement of each accelerometer frame."""
        pin.framesForwardKinematics(self.pin_model, self.data, q)
        return [self.data.oMf[f].copy() for f in self.sensor_frame_ids]

    def accelerometer_readings(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Noise-free specific force of every sensor in its own frame, eq. (9) stacked.

        f = R_WS^T (a_W - g_W), a_W the classical acceleration of the sensor point.
        """
        pin.forwardKinematics(self.pin_model, self.data, q, dq, ddq)
        return self._specific_forces()

    def _specific_forces(self) -> np.ndarray:
        """Readings from the kinematics already in ``data`` (q, q', q'')."""
        model, data = self.pin_model, self.data
        pin.updateFramePlacements(model, data)
        out = np.empty(3 * self.n_sensors)
        local = pin.ReferenceFrame.LOCAL
        for i, fid in enumerate(self.sensor_frame_ids):
            acc = pin.getFrameClassicalAcceleration(model, data, fid, local).linear
            out[3 * i : 3 * i + 3] = acc - data.oMf[fid].rotation.T @ self.gravity_vector
        return out

    def accelerometer_maps(self, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(T_A(q), W_A(q, q')) of eq. (10): readings = T_A q'' + W_A.

        One forward-kinematics pass (q, q', q'' = 0) gives W_A and the joint Jacobians,
        whose linear rows in the sensor frames stack into T_A.
        """
        model, data = self.pin_model, self.data
        pin.forwardKinematics(model, data, q, dq, self._zero_acceleration)
        W = self._specific_forces()
        pin.computeJointJacobians(model, data)  # from the placements just computed
        T = np.empty((3 * self.n_sensors, self.n))
        local = pin.ReferenceFrame.LOCAL
        for i, fid in enumerate(self.sensor_frame_ids):
            T[3 * i : 3 * i + 3] = pin.getFrameJacobian(model, data, fid, local)[:3]
        return T, W

    def with_accelerometers(self, mounts: tuple[AccelerometerMount, ...]) -> RobotModel:
        """Same model with another set of accelerometer mounts."""
        return RobotModel(self.spec, self.scaling, tuple(mounts), self.added_friction)
