"""Small URDF utilities shared by the simulator and the pinocchio model."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from functools import lru_cache
from pathlib import Path

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


def mesh_directory(path: str) -> str:
    """Folder against which relative mesh paths of the URDF are resolved."""
    return str(Path(path).parent)
