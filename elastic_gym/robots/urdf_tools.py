"""Small URDF utilities shared by the simulator and the pinocchio model."""

from __future__ import annotations

import hashlib
import os
import tempfile
import xml.etree.ElementTree as ET
from functools import lru_cache
from pathlib import Path

import numpy as np

UNBOUNDED = "1e9"


@lru_cache(maxsize=32)
def urdf_text_for_pinocchio(path: str) -> str:
    """URDF text with ``continuous`` joints turned into unbounded ``revolute`` ones.

    Pinocchio represents a continuous joint by (cos q, sin q), so its
    configuration would have 2N entries. The arms here need q in R^N (angles that
    may wind), which is a revolute joint whose limits are never active; pinocchio's
    dynamics ignore joint limits anyway.
    """
    tree = ET.parse(path)
    for joint in tree.getroot().iter("joint"):
        if joint.get("type") == "continuous":
            joint.set("type", "revolute")
            limit = joint.find("limit")
            if limit is None:
                limit = ET.SubElement(joint, "limit")
            limit.set("lower", f"-{UNBOUNDED}")
            limit.set("upper", UNBOUNDED)
            limit.set("effort", UNBOUNDED)
            limit.set("velocity", UNBOUNDED)
    return ET.tostring(tree.getroot(), encoding="unicode")


def joint_limits(path: str, joint_names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) position limits of the named joints (+-inf for continuous joints)."""
    limits = {}
    for joint in ET.parse(path).getroot().iter("joint"):
        limit = joint.find("limit")
        if joint.get("type") == "revolute" and limit is not None:
            limits[joint.get("name")] = (float(limit.get("lower", 0)), float(limit.get("upper", 0)))
    lower = np.array([limits.get(name, (-np.inf, np.inf))[0] for name in joint_names])
    upper = np.array([limits.get(name, (-np.inf, np.inf))[1] for name in joint_names])
    return lower, upper


@lru_cache(maxsize=32)
def urdf_without_limits(path: str) -> str:
    """Path of a copy of the URDF whose revolute joints are ``continuous``.

    PyBullet enforces URDF joint limits with hidden constraint forces, which the
    nominal model (and every observer) knows nothing about. The env instead ends an
    episode when a limit is crossed, so the simulator gets a limit-free copy (mesh
    paths made absolute). URDFs without limited joints are returned unchanged. The
    copy is cached in the temp folder under a content hash (safe across processes).
    """
    tree = ET.parse(path)
    root = tree.getroot()
    limited = [j for j in root.iter("joint") if j.get("type") == "revolute"]
    if not limited:
        return path
    for joint in limited:
        joint.set("type", "continuous")
        limit = joint.find("limit")
        if limit is not None:
            joint.remove(limit)
    base = Path(path).parent
    for mesh in root.iter("mesh"):
        filename = mesh.get("filename", "")
        if filename and "://" not in filename and not os.path.isabs(filename):
            mesh.set("filename", str(base / filename))
    text = ET.tostring(root, encoding="unicode")
    digest = hashlib.sha1(text.encode()).hexdigest()[:16]
    folder = Path(tempfile.gettempdir()) / "elastic_gym_urdf"
    folder.mkdir(exist_ok=True)
    target = folder / f"{Path(path).stem}_{digest}.urdf"
    if not target.exists():
        scratch = folder / f".{target.name}.{os.getpid()}"
        scratch.write_text(text)
        os.replace(scratch, target)
    return str(target)
