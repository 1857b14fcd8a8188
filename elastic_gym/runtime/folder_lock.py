"""One writer per output folder: an exclusive lock, and a check that the folder can be written.

`folder_lock` holds an exclusive ``fcntl.flock`` on the file `LOCK_FILE` in
the folder for as long as a comparison or a training writes there; a second writer is
refused at once (`FolderLockedError`, naming the folder and the holder's pid).
The kernel releases the lock when its holder ends, however it ends (``kill -9``
included), so a lock file left behind never blocks a later run; a holder that ends
normally removes it.

`check_writable` tells before any work whether files can be created where the
folder is (or would be created).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TextIO

LOCK_FILE = ".elastic_gym.lock"


class FolderLockedError(FileExistsError):
    """Another process writes into the folder (``holder``: its pid, ``None`` if unknown)."""

    def __init__(self, folder: Path, holder: int | None) -> None:
        who = f"process {holder}" if holder is not None else "another process"
        super().__init__(
            f"output folder {str(folder)!r} is in use by {who} (lock file "
            f"{LOCK_FILE}); wait for it to end or choose another folder"
        )
        self.folder = folder
        self.holder = holder


def _holder(handle: TextIO) -> int | None:
    handle.seek(0)
    text = handle.read().strip()
    return int(text) if text.isdigit() else None


def nearest_existing(folder: Path) -> Path:
    """``folder`` or its closest ancestor that exists."""
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    return existing


def check_writable(folder: str | Path) -> None:
    """Raise before any work if no file can be created in ``folder`` (or, if it does not
    exist yet, in the ancestor it would be created in); creates nothing.

    ``NotADirectoryError``: that path is a file. ``PermissionError``: it cannot be
    written (permissions, a read-only file system), with the system's reason.
    """
    folder = Path(folder)
    existing = nearest_existing(folder)
    if not existing.is_dir():
        raise NotADirectoryError(
            f"output folder {str(folder)!r}: {str(existing)!r} is a file, not a folder"
        )
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as exc:
        raise PermissionError(
            f"output folder {str(folder)!r}: cannot write in "
            f"{str(existing)!r} ({exc.strerror or exc})"
        ) from None


def check_free(
    folder: str | Path,
    earlier: Callable[[], list[str]],
    holds: str,
    choose: str,
    overwrite: bool = False,
    held: bool = False,
) -> None:
    """Raise before any work if ``folder`` cannot receive new outputs; changes nothing:
    `check_writable`, `check_unlocked` (another process writes there: its outputs so far
    are not an earlier job's), then ``FileExistsError`` if it holds the outputs of an
    earlier job (``earlier()``: their names; ``holds`` says what they are, ``choose`` the
    option that picks another folder) and not ``overwrite``. ``held``: the caller (or the
    process that started it) holds the folder's lock."""
    check_writable(folder)
    if not held:
        check_unlocked(folder)
    found = [] if overwrite else earlier()
    if found:
        shown = ", ".join(found[:5]) + (", ..." if len(found) > 5 else "")
        raise FileExistsError(
            f"output folder {str(folder)!r} holds {holds} ({shown}); choose another "
            f"{choose}, or replace it with --overwrite (overwrite=True)"
        )


_HELD: set[Path] = set()  # folders whose lock this process holds (resolved)


def check_unlocked(folder: str | Path) -> None:
    """Raise `FolderLockedError` (naming the holder's pid) if another process holds the
    folder's writer lock; takes no lock and creates nothing. A folder whose lock this
    process holds (`folder_lock`) passes."""
    folder = Path(folder)
    path = folder / LOCK_FILE
    if folder.resolve() in _HELD or not path.is_file():
        return
    try:
        handle = path.open("r")
    except OSError:  # gone meanwhile, or unreadable: the lock itself decides
        return
    with handle:
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            raise FolderLockedError(folder, _holder(handle)) from None
        fcntl.flock(handle.fileno(), fcntl.LOCK_UN)


def _acquire(path: Path) -> TextIO:
    """Open and lock ``path``; retry if another holder unlinked it meanwhile."""
    while True:
        handle = path.open("a+")
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(handle)
            handle.close()
            raise FolderLockedError(path.parent, holder) from None
        try:
            same = os.stat(path).st_ino == os.fstat(handle.fileno()).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return handle
        handle.close()  # locked a file its last holder had already removed


@contextlib.contextmanager
def folder_lock(folder: str | Path) -> Iterator[Path]:
    """Hold the folder's writer lock inside the block.

    The folder is created if needed, and removed again at the end if this call created
    it and it is left empty (a refused run leaves nothing behind); the lock file is
    removed at the end. Raises `FolderLockedError` at once if another process
    (or another ``folder_lock`` in this one) holds the lock.
    """
    folder = Path(folder)
    created = [f for f in (folder, *folder.parents) if not f.exists()]
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_FILE
    try:
        handle = _acquire(path)
    except BaseException:
        _remove_empty(created)
        raise
    held = folder.resolve()
    try:
        handle.seek(0)
        handle.truncate()
        handle.write(f"{os.getpid()}\n")
        handle.flush()
        _HELD.add(held)
        yield folder
    finally:
        _HELD.discard(held)
        with contextlib.suppress(OSError):
            path.unlink()  # while still holding the lock: see _acquire
        handle.close()  # releases the lock
        _remove_empty(created)


def _remove_empty(created: list[Path]) -> None:
    for made in created:  # deepest first
        with contextlib.suppress(OSError):
            made.rmdir()
