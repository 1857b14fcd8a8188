"""Files that are either the old version or the whole new one, never a truncated mix.

A result file (a scorecard, a table, a figure, a run folder's config) is written to a
temporary file beside its target and moved over it with `os.replace`, which POSIX makes
atomic within one file system: a process interrupted or a disk that fills while writing
leaves the earlier file (or none) and removes the temporary one; a process killed outright
(SIGKILL) cannot remove it, and `leftovers` finds it. The new file gets the mode of the
file it replaces, or that of a file `open` would create (0o666 less the umask).
"""

from __future__ import annotations

import contextlib
import glob
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike, mode: str = "w", **open_kwargs: Any) -> Iterator[IO]:
    """Open a temporary file beside `path` for writing (`mode` "w" or "wb"); on a normal
    exit it is flushed to disk and renamed to `path`; on an exception it is removed and
    `path` is left as it was."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_file writes whole files: mode 'w' or 'wb', got {mode!r}")
    target = Path(path)
    handle, scratch = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent)
    try:
        os.fchmod(handle, _mode_of(target))  # mkstemp makes it 0o600
        with open(handle, mode, **open_kwargs) as stream:
            yield stream
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(scratch, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(scratch)
        raise


def leftovers(path: str | os.PathLike) -> list[Path]:
    """The temporary files of `atomic_file` writes of ``path`` that never finished (their
    process was killed outright mid-write)."""
    target = Path(path)
    return sorted(target.parent.glob(f".{glob.escape(target.name)}.*.part"))


def _mode_of(target: Path) -> int:
    """The permission bits of ``target``, or those a new file gets (0o666 less the umask)."""
    try:
        return target.stat().st_mode & 0o7777
    except OSError:
        umask = os.umask(0o022)
        os.umask(umask)
        return 0o666 & ~umask


def write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write `text` to `path` atomically (`atomic_file`); returns the path."""
    with atomic_file(path, "w", encoding=encoding, newline="") as stream:
        stream.write(text)
    return Path(path)


def write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write `data` to `path` atomically (`atomic_file`); returns the path."""
    with atomic_file(path, "wb") as stream:
        stream.write(data)
    return Path(path)
