"""PyBullet plant with elastic transmissions integrated next to each physics step.

Links are simulated by PyBullet (``p.DIRECT``, one client per simulator, fixed base,
``URDF_USE_INERTIA_FROM_FILE``, default velocity motors disabled, every
PyBullet-added damping set to zero, pure torque control). The motor side of the
elastic joints is integrated in numpy with the same semi-implicit Euler scheme
PyBullet uses for the links, one substep at a time:

* model (1): tau_J = K (theta - q) + D (theta' - q') is applied to the link joint,
  theta'' = B^-1 (tau - tau_J);
* model (2) (constant S): the coupled accelerations are solved with the plant's
  pinocchio model, (M - S B^-1 S^T) q'' = tau_J - S B^-1 (tau - tau_J) - n - d,
  theta'' = B^-1 (tau - tau_J - S^T q''), and tau_link = tau_J - S theta'' is applied
  to PyBullet, which then produces that q'' (DESIGN.md, option (b));
* rigid joints: the motor torque acts on the link directly.

Link friction d(q') (when the robot has it) is applied explicitly from the state at
the start of each substep. URDF joint limits are not enforced by PyBullet (they would
act as hidden constraint forces); the env ends the episode when a limit is crossed.
"""

from __future__ import annotations

import contextlib
import os
import sys

import numpy as np
import pybullet as p

from elastic_gym.model import RobotModel
from elastic_gym.robots.spec import RobotSpec
from elastic_gym.robots.urdf_tools import urdf_without_limits


class ArmSimulator:
    """One PyBullet client holding one arm, plus the numpy motor state.

    Args:
        spec: the robot.
        plant: the exact pinocchio model of the simulated plant (same URDF and the
            same parameter scaling); used for model (2) and for the true q''.
        physics_dt: physics step (s).
        gui: connect with ``p.GUI`` instead of ``p.DIRECT`` (render_mode="human").
    """

    def __init__(self, spec: RobotSpec, plant: RobotModel, physics_dt: float, gui: bool = False):
        self.spec = spec
        self.plant = plant
        self.n = spec.n_joints
        self.physics_dt = float(physics_dt)
        if gui:
            if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
                # p.connect(p.GUI) without an X server terminates the whole process.
                raise RuntimeError("render_mode='human' needs a display (DISPLAY is not set)")
            self.client = p.connect(p.GUI)
            if self.client < 0:
                raise RuntimeError("render_mode='human' needs a display for the PyBullet GUI")
        else:
            self.client = p.connect(p.DIRECT)
        self._connected = True
        c = self.client
        p.resetSimulation(physicsClientId=c)
        p.setGravity(*spec.gravity, physicsClientId=c)
        p.setTimeStep(self.physics_dt, physicsClientId=c)
        p.setPhysicsEngineParameter(numSubSteps=0, physicsClientId=c)
        self.body = p.loadURDF(
            urdf_without_limits(spec.urdf),
            useFixedBase=True,
            flags=p.URDF_USE_INERTIA_FROM_FILE,
            physicsClientId=c,
        )
        name_to_index = {
            p.getJointInfo(self.body, j, physicsClientId=c)[1].decode(): j
            for j in range(p.getNumJoints(self.body, physicsClientId=c))
        }
        missing = [name for name in spec.joint_names if name not in name_to_index]
        if missing:
            raise ValueError(f"joints {missing} not found in {spec.urdf}")
        self.joint_indices = [name_to_index[name] for name in spec.joint_names]
        self._configure_dynamics(name_to_index)

        self.q = np.zeros(self.n)
        self.dq = np.zeros(self.n)
        self.theta = np.zeros(self.n)
        self.dtheta = np.zeros(self.n)
        self.last_link_torque = np.zeros(self.n)
        self._zeros = np.zeros(self.n)

    # ------------------------------------------------------------------ setup
    def _configure_dynamics(self, name_to_index: dict[str, int]) -> None:
        """Zero all damping, disable default motors, apply the plant's link scaling."""
        c, body = self.client, self.body
        n_links = p.getNumJoints(body, physicsClientId=c)
        owner = self._owning_joint(n_links)
        mass_scale = self.plant.scaling.per_joint("link_mass", self.n)
        inertia_scale = self.plant.scaling.per_joint("link_inertia", self.n)
        for link in range(-1, n_links):
            # One property per call: PyBullet 3.2.7 silently drops jointDamping when it is
            # passed together with other properties (measured: URDF damping stayed active).
            for prop in ({"linearDamping": 0.0}, {"angularDamping": 0.0},
                         {"jointDamping": 0.0}, {"maxJointVelocity": 1e4}):
                p.changeDynamics(body, link, **prop, physicsClientId=c)
            j = owner.get(link)
            if j is not None and (mass_scale[j] != 1.0 or inertia_scale[j] != 1.0):
                info = p.getDynamicsInfo(body, link, physicsClientId=c)
                mass, inertia = info[0], np.asarray(info[2])
                p.changeDynamics(
                    body, link, mass=mass * mass_scale[j],
                    localInertiaDiagonal=(inertia * mass_scale[j] * inertia_scale[j]).tolist(),
                    physicsClientId=c,
                )
        for j in range(n_links):
            p.setJointMotorControl2(
                body, j, p.VELOCITY_CONTROL, targetVelocity=0.0, force=0.0, physicsClientId=c
            )

    def _owning_joint(self, n_links: int) -> dict[int, int]:
        """Map each PyBullet link to the actuated joint that moves it (fixed children inherit)."""
        c, body = self.client, self.body
        actuated = {idx: k for k, idx in enumerate(self.joint_indices)}
        owner: dict[int, int] = {}
        for link in range(n_links):
            j = link
            while j >= 0 and j not in actuated:
                j = p.getJointInfo(body, j, physicsClientId=c)[16]
            if j >= 0:
                owner[link] = actuated[j]
        return owner

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> np.ndarray:
        """x = (theta, q, theta', q') (rigid arms: theta = q)."""
        return np.concatenate([self.theta, self.q, self.dtheta, self.dq])

    def reset_state(
        self, q: np.ndarray, dq: np.ndarray, theta: np.ndarray, dtheta: np.ndarray
    ) -> None:
        c = self.client
        for k, j in enumerate(self.joint_indices):
            p.resetJointState(self.body, j, float(q[k]), float(dq[k]), physicsClientId=c)
        self.q, self.dq = np.array(q, dtype=float), np.array(dq, dtype=float)
        if self.spec.elastic:
            self.theta, self.dtheta = np.array(theta, dtype=float), np.array(dtheta, dtype=float)
        else:
            self.theta, self.dtheta = self.q, self.dq

    def _read_links(self) -> None:
        states = p.getJointStates(self.body, self.joint_indices, physicsClientId=self.client)
        self.q = np.array([s[0] for s in states])
        self.dq = np.array([s[1] for s in states])

    # ------------------------------------------------------------------ stepping
    def link_torque(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(torque applied to the PyBullet joints, motor acceleration) for motor torque tau."""
        plant = self.plant
        if not self.spec.elastic:
            link_tau, ddtheta = tau, self._zeros
        else:
            tau_j = plant.K * (self.theta - self.q) + plant.D * (self.dtheta - self.dq)
            if plant.has_coupling:
                ddtheta, _ = plant.elastic_accelerations(self.state, tau)
                link_tau = tau_j - plant.S @ ddtheta
            else:
                link_tau, ddtheta = tau_j, plant.B_inv * (tau - tau_j)
        if plant.friction is not None:
            link_tau = link_tau - plant.friction.torque(self.dq)
        return link_tau, ddtheta

    def step(self, tau: np.ndarray, n_substeps: int) -> None:
        """Advance ``n_substeps`` physics steps holding the motor torque ``tau``."""
        c, body, dt, joints = self.client, self.body, self.physics_dt, self.joint_indices
        elastic = self.spec.elastic
        for _ in range(n_substeps):
            link_tau, ddtheta = self.link_torque(tau)
            p.setJointMotorControlArray(
                body, joints, p.TORQUE_CONTROL, forces=link_tau.tolist(), physicsClientId=c
            )
            p.stepSimulation(physicsClientId=c)
            if elastic:
                self.dtheta = self.dtheta + dt * ddtheta
                self.theta = self.theta + dt * self.dtheta
            self._read_links()
            if not elastic:
                self.theta, self.dtheta = self.q, self.dq
            self.last_link_torque = link_tau

    def link_acceleration(self, tau: np.ndarray) -> np.ndarray:
        """True q'' at the current state under motor torque tau (plant model, exact)."""
        plant = self.plant
        if not self.spec.elastic:
            return plant.rigid_acceleration(self.q, self.dq, tau)
        return plant.elastic_accelerations(self.state, tau)[1]

    def link_pose(self, link_name: str) -> tuple[np.ndarray, np.ndarray]:
        """World position and rotation matrix of a URDF link frame, from PyBullet."""
        c = self.client
        for j in range(p.getNumJoints(self.body, physicsClientId=c)):
            if p.getJointInfo(self.body, j, physicsClientId=c)[12].decode() == link_name:
                state = p.getLinkState(self.body, j, computeForwardKinematics=1, physicsClientId=c)
                rot = np.asarray(p.getMatrixFromQuaternion(state[5])).reshape(3, 3)
                return np.asarray(state[4]), rot
        raise ValueError(f"link {link_name!r} not in the URDF")

    # ------------------------------------------------------------------ rendering
    def render(self, width: int = 480, height: int = 360) -> np.ndarray:
        """RGB image (H, W, 3) from the offscreen tiny renderer."""
        target, distance, yaw, pitch = self.spec.camera
        c = self.client
        view = p.computeViewMatrixFromYawPitchRoll(
            target, distance, yaw, pitch, 0.0, 2, physicsClientId=c
        )
        proj = p.computeProjectionMatrixFOV(60.0, width / height, 0.05, 50.0, physicsClientId=c)
        _, _, rgba, _, _ = p.getCameraImage(
            width, height, view, proj, renderer=p.ER_TINY_RENDERER, physicsClientId=c
        )
        return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[:, :, :3]

    def close(self) -> None:
        if self._connected:
            self._connected = False
            with contextlib.suppress(p.error):
                p.disconnect(physicsClientId=self.client)

    def __del__(self) -> None:  # pragma: no cover - best effort cleanup
        with contextlib.suppress(Exception):
            self.close()
