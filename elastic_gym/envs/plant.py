"""The simulated plants of N arms: one exact model per arm, stacked for the simulator.

Arm k of a batch may have its own plant (``per_arm``, ``randomize``): parameter scaling,
unmodelled link friction and a payload. `PlantArray` keeps one
[`RobotModel`][elastic_gym.model.RobotModel] per arm (exactly the plant model a single env with
that arm's kwargs builds) and the arrays with a leading arm axis that the simulator's
kernels read: K, D, B^-1, the model (2) constants S, S B^-1, -S B^-1 S^T, S^T, the link
friction coefficients and a [`SerialChain`][elastic_gym.model.SerialChain] stacked from the arms'
chains (per-arm link inertias for the Schur solve of model (2) and the true q'').

A payload is a point mass m at a point p of the last actuated link's frame (default: twice
that link's centre of mass, the tip of a uniform link); the plant's last link inertia
becomes I + (m, p, 0) (a point mass has no rotational inertia about itself), and the
PyBullet body carries a fixed child link of mass m at p (`payload_urdf`).
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from functools import lru_cache

import numpy as np
import pinocchio as pin

from elastic_gym.model import RobotModel, SerialChain
from elastic_gym.robots.spec import RobotSpec

PAYLOAD_LINK = "elastic_gym_payload"


def default_payload_position(model: RobotModel) -> np.ndarray:
    """Twice the last link's centre of mass in its own frame: the tip of a uniform link."""
    return 2.0 * np.asarray(model.pin_model.inertias[model.n].lever, dtype=float)


def with_payload(model: RobotModel, mass: float, position: Sequence[float]) -> RobotModel:
    """A copy of ``model`` whose last link carries a point mass ``mass`` at ``position``."""
    new = model.copy()
    n = new.n
    new.pin_model.inertias[n] = new.pin_model.inertias[n] + pin.Inertia(
        float(mass), np.asarray(position, dtype=float), np.zeros((3, 3))
    )
    return new


def last_link(spec: RobotSpec) -> str:
    """Name of the URDF link moved by the last actuated joint."""
    root = ET.parse(spec.urdf).getroot()
    for joint in root.iter("joint"):
        child = joint.find("child")
        if joint.get("name") == spec.joint_names[-1] and child is not None:
            return str(child.get("link"))
    raise ValueError(f"joint {spec.joint_names[-1]!r} not in {spec.urdf}")


@lru_cache(maxsize=64)
def payload_urdf(urdf: str, link: str, position: tuple[float, ...]) -> str:
    """A copy of ``urdf`` with a massless fixed child link of ``link`` at ``position``
    (its mass is set per arm with ``changeDynamics``); cached in the temp folder."""
    root = ET.parse(urdf).getroot()
    xyz = " ".join(repr(float(x)) for x in position)
    child = ET.SubElement(root, "link", name=PAYLOAD_LINK)
    inertial = ET.SubElement(child, "inertial")
    ET.SubElement(inertial, "origin", xyz="0 0 0", rpy="0 0 0")
    ET.SubElement(inertial, "mass", value="0")
    ET.SubElement(inertial, "inertia", ixx="0", ixy="0", ixz="0", iyy="0", iyz="0", izz="0")
    joint = ET.SubElement(root, "joint", name=PAYLOAD_LINK + "_joint", type="fixed")
    ET.SubElement(joint, "parent", link=link)
    ET.SubElement(joint, "child", link=PAYLOAD_LINK)
    ET.SubElement(joint, "origin", xyz=xyz, rpy="0 0 0")
    text = ET.tostring(root, encoding="unicode")
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    path = os.path.join(tempfile.gettempdir(), f"elastic_gym_payload_{digest}.urdf")
    if not os.path.exists(path):
        tmp = f"{path}.{os.getpid()}"
        with open(tmp, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    return path


class PlantArray:
    """Per-arm plant models and the stacked arrays of `ArmSimulator`'s kernels.

    Args:
        models: one plant model per arm (same robot and accelerometer mounts).
    """

    def __init__(self, models: Sequence[RobotModel]) -> None:
        self.models = list(models)
        self.n_arms = N = len(self.models)
        self.n = n = self.models[0].n
        self.K, self.D, self.B_inv = np.zeros((N, n)), np.zeros((N, n)), np.zeros((N, n))
        self.S, self.SBinv = np.zeros((N, n, n)), np.zeros((N, n, n))
        self.schur_inertia, self.ST = np.zeros((N, n, n)), np.zeros((N, n, n))
        self.viscous, self.coulomb_pos = np.zeros((N, n)), np.zeros((N, n))
        self.coulomb_neg, self.smoothing = np.zeros((N, n)), np.ones(N)
        self.chain = SerialChain.stack([m.chain for m in self.models])
        self.has_coupling = self.has_friction = self.has_coulomb = False
        for arm, model in enumerate(self.models):
            self.set(arm, model)

    def set(self, arm: int, model: RobotModel) -> None:
        """Give arm ``arm`` the plant ``model``."""
        self.models[arm] = model
        self.K[arm], self.D[arm], self.B_inv[arm] = model.K, model.D, model.B_inv
        SBinv = model.S * model.B_inv
        self.S[arm], self.SBinv[arm] = model.S, SBinv
        self.schur_inertia[arm] = -SBinv @ model.S.T
        self.ST[arm] = model.S.T
        friction, n = model.friction, self.n
        if friction is not None:
            positive, negative = friction.coulomb_pos, friction.negative_coulomb()
            self.viscous[arm] = np.asarray(friction.viscous, dtype=float) * np.ones(n)
            self.coulomb_pos[arm] = 0.0 if positive is None else np.asarray(positive) * np.ones(n)
            self.coulomb_neg[arm] = 0.0 if negative is None else np.asarray(negative) * np.ones(n)
            self.smoothing[arm] = friction.smoothing_velocity
        else:
            self.viscous[arm] = self.coulomb_pos[arm] = self.coulomb_neg[arm] = 0.0
            self.smoothing[arm] = 1.0
        self.chain.set_row(arm, model.chain)
        models = self.models
        self.has_coupling = any(m.has_coupling for m in models)
        self.has_friction = any(m.friction is not None for m in models)
        self.has_coulomb = any(
            m.friction is not None and m.friction.coulomb_pos is not None for m in models
        )
        # the transmission kernel's constants in its argument order (arrays changed in place)
        self.transmission = (
            self.K,
            self.D,
            self.B_inv,
            self.viscous,
            self.coulomb_pos,
            self.coulomb_neg,
            self.smoothing,
            self.has_friction,
            self.has_coulomb,
        )
