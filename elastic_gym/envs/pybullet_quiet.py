"""PyBullet imported without its build banner.

The module initialisation of PyBullet writes ``pybullet build time: ...`` to the C-level
standard error of every process that imports it, so each command (and each worker
process) started with it. The first import goes through here with file descriptor 2
pointed at the null device; later imports of ``pybullet`` get the module already loaded.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator


@contextlib.contextmanager
def stderr_silenced() -> Iterator[None]:
    """Send what C code writes to file descriptor 2 to the null device while the block
    runs (Python's own ``sys.stderr`` is flushed first and keeps working afterwards)."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no file descriptor 2: nothing to silence
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


with stderr_silenced():
    import pybullet

__all__ = ["pybullet"]
