"""The memory a batch of arms needs, checked before PyBullet builds it.

PyBullet gives no exception when an allocation fails while it loads bodies: a batch
too large for the machine ends the process with a segmentation fault inside
``loadURDF``. `check_batch_memory` refuses such a batch first, with the numbers.

The estimate (`batch_bytes`) is linear in the number of arms: per arm
`ARM_BYTES` (a body of a few primitive-shape links with its joint and solver
data) plus `MESH_FACTOR` times the size of the mesh files its URDF references
(PyBullet keeps its own copy of each mesh's collision and visual data per body); both
constants are rounded up from the resident memory of batches of 1000 arms of the
shipped robots. What is available (`available_bytes`) is the kernel's
``MemAvailable``, lowered to the room left under a cgroup memory limit if one is set.
"""

from __future__ import annotations

import contextlib
import xml.etree.ElementTree as ElementTree
from functools import lru_cache
from pathlib import Path

ARM_BYTES = 128 * 1024
MESH_FACTOR = 3
USABLE_SHARE = 0.9  # of the available memory a batch may take
GIB = 1024**3


@lru_cache(maxsize=32)
def mesh_bytes(urdf: str) -> int:
    """Total size of the mesh files the URDF references (missing files count 0)."""
    path = Path(urdf)
    try:
        root = ElementTree.parse(path).getroot()
    except (OSError, ElementTree.ParseError):
        return 0
    files = {mesh.get("filename", "") for mesh in root.iter("mesh")}
    total = 0
    for name in files:
        file = path.parent / name.removeprefix("file://")
        with contextlib.suppress(OSError):
            total += file.stat().st_size
    return total


def batch_bytes(urdf: str, n_arms: int) -> int:
    """Estimated memory of ``n_arms`` copies of the URDF's arm in one PyBullet world."""
    return n_arms * (ARM_BYTES + MESH_FACTOR * mesh_bytes(urdf))


def _read_int(path: str) -> int | None:
    try:
        text = Path(path).read_text().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def available_bytes() -> int | None:
    """Memory this process can still take (``None`` where the system does not say)."""
    available = None
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                available = int(line.split()[1]) * 1024
    for limit_file, usage_file in (
        ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
        (
            "/sys/fs/cgroup/memory/memory.limit_in_bytes",
            "/sys/fs/cgroup/memory/memory.usage_in_bytes",
        ),
    ):
        limit, usage = _read_int(limit_file), _read_int(usage_file)
        if limit is not None and usage is not None:
            room = max(0, limit - usage)
            available = room if available is None else min(available, room)
            break
    return available


def check_batch_memory(urdf: str, n_arms: int, robot: str) -> None:
    """Raise ``ValueError`` if ``n_arms`` arms cannot fit in the memory available now."""
    needed = batch_bytes(urdf, n_arms)
    available = available_bytes()
    if available is not None and needed > USABLE_SHARE * available:
        raise ValueError(
            f"n_arms={n_arms}: a batch of {n_arms} {robot} arms needs about "
            f"{needed / GIB:.1f} GiB of memory, and {available / GIB:.1f} GiB are available "
            f"(at most {USABLE_SHARE:.0%} of it is used); use at most "
            f"{int(USABLE_SHARE * available // (needed / n_arms))} arms per batch"
        )
