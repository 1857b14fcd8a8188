"""The folder of one training run: created, refused or overwritten, removed on failure,
loaded back, and old folders migrated.

A run folder holds ``model.zip``, ``vecnormalize.pkl``, ``best_model.zip``, ``config.yaml``,
``summary.json`` (written last: a folder with it holds a finished run), ``evaluations.npz``,
``learning_curve.csv`` and ``tb/``; ``config.yaml`` and ``summary.json`` are written whole
or not at all (`elastic_gym.runtime.atomic`). A folder holding a run is refused unless
``overwrite``: then the new run is written beside it, in ``.incoming/``, and replaces the
earlier run's files (only those) once complete (`NewRun.finish`); until then the earlier
run stays whole, and a run that fails or is interrupted leaves it as it was and removes
what it wrote (`RunFolder.create`). ``config.yaml`` is self-contained; a folder of an
earlier release is migrated when read (`MIGRATIONS`). ``model.zip`` and
``vecnormalize.pkl`` are pickles: load only run folders from trusted sources.
"""

from __future__ import annotations

import contextlib
import json
import os
import pickle
import shutil
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import yaml

from elastic_gym.runtime.atomic import leftovers, write_text
from elastic_gym.runtime.folder_lock import (
    check_free,
    check_unlocked,
    check_writable,
    folder_lock,
)
from elastic_gym.schemas import schema_comment
from elastic_gym.training.config import TrainConfig, algorithm_class
from elastic_gym.yaml_io import load_yaml

RUN_FILES = ("model.zip", "vecnormalize.pkl", "config.yaml")  # needed to load a run
CURVE_FILE = "learning_curve.csv"  # the learning curve (elastic_gym.training.learning_curve)
FINISHED = "summary.json"
RUN_OUTPUTS = (*RUN_FILES, "best_model.zip", FINISHED, "evaluations.npz", CURVE_FILE, "tb")
INCOMING = ".incoming"  # a run that will replace the folder's earlier run, while it is written
REPLACING = ".replacing"  # the earlier run's files while they are moved aside
REPLACED = ".replaced"  # the earlier run's files while the new run's are moved in


def _before_the_deadzone(data: Any) -> Any:
    """A run saved before actions had ``residual_deadzone`` applied its residual without
    one: say so explicitly, so that today's default does not change its actions."""
    if not isinstance(data, dict):
        return data  # not a config: refused by TrainConfig
    action = data.get("action", {})
    hyperparams = data.get("hyperparams")
    shipped = hyperparams.get("action") if isinstance(hyperparams, dict) else None
    if not isinstance(action, dict) or any(
        isinstance(part, dict) and "residual_deadzone" in part for part in (action, shipped)
    ):
        return data
    return {**data, "action": {**action, "residual_deadzone": 0.0}}


# Applied in order to a saved config.yaml before it is validated: each makes a folder
# written before a field existed mean what it meant when it was written.
MIGRATIONS: tuple[Callable[[Any], Any], ...] = (_before_the_deadzone,)


def missing_folders(path: str | Path) -> list[Path]:
    """``path`` and those of its parents that do not exist yet, deepest first."""
    path = Path(path)
    return [folder for folder in (path, *path.parents) if not folder.exists()]


def remove_empty(folders: Iterable[Path]) -> None:
    """Remove those of ``folders`` that are empty, deepest first (others are kept)."""
    for folder in sorted(folders, key=lambda f: len(f.parts), reverse=True):
        with contextlib.suppress(OSError):  # not empty, gone, or the current directory
            folder.rmdir()


class RunFolder:
    """The folder of one training run (module docstring).

    Args:
        path: the folder (``TrainConfig.out_dir``).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunFolder({str(self.path)!r})"

    @property
    def finished(self) -> bool:
        """Whether the folder holds a finished run (its summary is written last)."""
        return (self.path / FINISHED).is_file()

    def summary_stamp(self) -> tuple[int, int] | None:
        """Identity of the folder's ``summary.json`` (inode, modification time in ns; None
        without one): a new run's summary, written atomically, has another."""
        try:
            stat = (self.path / FINISHED).stat()
        except OSError:
            return None
        return stat.st_ino, stat.st_mtime_ns

    def earlier_run(self) -> list[str]:
        """Files of an earlier run in the folder or in its ``seed*`` sub-folders."""
        found = []
        for directory in (self.path, *sorted(self.path.glob("seed*"))):
            found += [
                str((directory / name).relative_to(self.path))
                for name in RUN_OUTPUTS
                if (directory / name).exists()
            ]
        return found

    def check(self, overwrite: bool = False, held: bool = False) -> None:
        """Raise if the folder cannot receive a run (changes nothing): ``NotADirectoryError``
        if it is a file, ``PermissionError`` if it cannot be written (a read-only file
        system, `check_writable`), `FolderLockedError` if another process writes in it
        (unless ``held``: this process or the one that started it holds its lock),
        ``FileExistsError`` if it holds an earlier run and not ``overwrite``. The ``seed*``
        sub-folders of several seeds' runs are checked for a writer too."""
        if not held:
            for run in sorted(self.path.glob("seed*")):
                check_unlocked(run)
        check_free(self.path, self.earlier_run, "an earlier run", "--out", overwrite, held)

    def lock(self) -> contextlib.AbstractContextManager:
        """The folder's writer lock for a ``with`` block
        ([`folder_lock`][elastic_gym.runtime.folder_lock.folder_lock]: another writer is
        refused with `FolderLockedError`); checked writable first."""
        check_writable(self.path)
        return folder_lock(self.path)

    @contextlib.contextmanager
    def create(self, overwrite: bool = False, lock: bool = True) -> Iterator[NewRun]:
        """The run to write, for the ``with`` block that writes it into ``run.target``.

        Under the folder's writer lock ([`lock`][elastic_gym.training.run_folder.RunFolder.lock];
        ``lock=False``: the caller, or the process that started this one, holds it),
        checked ([`check`][elastic_gym.training.run_folder.RunFolder.check]). Without an
        earlier run the target is the folder itself; with ``overwrite`` and an earlier run
        it is the ``.incoming`` sub-folder, whose files replace the earlier run's when the
        run finishes ([`NewRun.finish`][elastic_gym.training.run_folder.NewRun.finish], or
        at the end of the block). If the block raises or is interrupted before, what the
        run wrote is removed, and the folders made for it if left empty; an earlier run is
        kept as it was. A ``KeyboardInterrupt`` becomes `Interrupted` saying which.
        """
        from elastic_gym.runtime.parallel import Interrupted

        with self.lock() if lock else contextlib.nullcontext():
            self.recover()
            self.check(overwrite, held=True)
            created = missing_folders(self.path)
            self.path.mkdir(parents=True, exist_ok=True)
            run = NewRun(self, replaces=bool(self.earlier_run()))
            try:
                yield run
                run.finish()
            except BaseException as exc:
                done = run.abandon()
                remove_empty(created)
                if isinstance(exc, KeyboardInterrupt):
                    raise Interrupted.of(exc, done) from None
                raise

    def recover(self) -> None:
        """Undo what a process killed while writing left (under the lock: nobody else
        writes): its unfinished ``.incoming`` run is removed, and an earlier run it had
        begun to replace is put back."""
        shutil.rmtree(self.path / INCOMING, ignore_errors=True)
        replacing, replaced = self.path / REPLACING, self.path / REPLACED
        if replacing.is_dir():  # killed while the earlier run's files were moved aside
            _move_all(replacing, self.path)
            shutil.rmtree(replacing, ignore_errors=True)
        if replaced.is_dir():  # killed while the new run's files were moved in
            if not self.finished:  # its summary comes last: the run files here are its
                self.clear(keep_folder=True)
                _move_all(replaced, self.path)
            shutil.rmtree(replaced, ignore_errors=True)

    def undo_killed_writer(self) -> None:
        """Undo what a writer killed mid-run left in the folder or its ``seed*``
        sub-folders ([`recover`][elastic_gym.training.run_folder.RunFolder.recover], under
        each folder's lock: `FolderLockedError` if the writer is alive); with nothing to
        undo, takes no lock and changes nothing."""
        seeds = [RunFolder(p) for p in sorted(self.path.glob("seed*")) if p.is_dir()]
        for folder in (self, *seeds):
            if any((folder.path / name).exists() for name in (INCOMING, REPLACING, REPLACED)):
                with folder.lock():
                    folder.recover()

    def replace_with(self, incoming: Path) -> None:
        """Replace the folder's run by the complete run in ``incoming`` (a sub-folder): the
        earlier run's files are moved aside, then the new ones in (``summary.json`` last),
        then the earlier ones removed. If a move fails (or the process is killed), the
        earlier run is put back (here, or by the next run's
        [`recover`][elastic_gym.training.run_folder.RunFolder.recover])."""
        replacing, replaced = self.path / REPLACING, self.path / REPLACED
        try:
            for name in self.earlier_run():
                (replacing / name).parent.mkdir(parents=True, exist_ok=True)
                os.replace(self.path / name, replacing / name)
            replacing.mkdir(exist_ok=True)
            os.replace(replacing, replaced)  # all aside: the new run's files come in
            _move_all(incoming, self.path)
        except BaseException:
            self.recover()
            raise
        shutil.rmtree(replaced, ignore_errors=True)
        shutil.rmtree(incoming, ignore_errors=True)
        remove_empty(p for p in self.path.glob("seed*") if p.is_dir())

    def clear(self, keep_folder: bool = False) -> None:
        """Remove the files of a run (and of ``seed*`` sub-runs) from the folder, with the
        temporary files of their writes that a killed worker left
        (`elastic_gym.runtime.atomic.leftovers`), and the folders left empty
        (the folder itself too unless ``keep_folder``); nothing else."""
        if not self.path.is_dir():
            return
        for directory in (*sorted(self.path.glob("seed*")), self.path):
            if not directory.is_dir():
                continue
            for name in RUN_OUTPUTS:
                path = directory / name
                if path.is_dir():
                    shutil.rmtree(path)
                elif path.exists():
                    path.unlink()
                for scratch in leftovers(path):  # a write cut short by a killed worker
                    scratch.unlink(missing_ok=True)
            if not (keep_folder and directory == self.path):
                remove_empty([directory])

    # ------------------------------------------------------------------ files
    def write_config(self, config: TrainConfig) -> None:
        """``config.yaml``: the config as the run used it (self-contained: no pointer to
        a hyper-parameter file, every field of the action and observation configs), its
        first line naming the ``run`` schema
        ([`schema_comment`][elastic_gym.schemas.schema_comment])."""
        text = schema_comment("run") + yaml.safe_dump(config.to_dict(), sort_keys=False)
        write_text(self.path / "config.yaml", text)

    def write_summary(self, summary: dict) -> None:
        """``summary.json``: written last, it marks the run finished."""
        write_text(self.path / FINISHED, json.dumps(summary, indent=2))

    def read_config(self) -> TrainConfig:
        """The run's configuration (the folder checked, old folders migrated); a missing
        or invalid file raises ``ValueError`` naming it."""
        missing = [name for name in RUN_FILES if not (self.path / name).is_file()]
        if missing:
            why = f"missing {missing}" if self.path.is_dir() else "no such folder"
            raise ValueError(f"{self.path} is not a training run folder: {why}")
        path = self.path / "config.yaml"
        try:
            data = load_yaml(path)
            for migrate in MIGRATIONS:
                data = migrate(data)
            return TrainConfig.from_dict(data)
        except (TypeError, ValueError) as exc:  # YAMLInputError is a ValueError
            raise ValueError(
                f"{path} is not a valid run configuration: {' '.join(str(exc).split())}"
            ) from None

    def load_model(self, algo: str, best: bool = False):
        """The SB3 model (``best``: the learning curve's best, if saved); unpickles."""
        best_path = self.path / "best_model.zip"
        path = best_path if best and best_path.exists() else self.path / "model.zip"
        return _loaded(path, f" as a {algo} model", algorithm_class(algo).load, device="cpu")

    def load_normalizer(self):
        """The saved ``VecNormalize`` statistics, frozen (not updated); unpickles."""
        return _loaded(self.path / "vecnormalize.pkl", "", _frozen_normalizer)


class NewRun:
    """A run being written ([`RunFolder.create`][elastic_gym.training.run_folder.RunFolder.create]):
    its files go to ``target``, the run folder itself or, when the run ``replaces`` an
    earlier one, the folder's ``.incoming`` sub-folder."""

    def __init__(self, folder: RunFolder, replaces: bool) -> None:
        self.folder = folder
        self.replaces = replaces
        self.target = RunFolder(folder.path / INCOMING) if replaces else folder
        self.target.path.mkdir(exist_ok=True)
        self.finished = False

    def finish(self) -> None:
        """The run is complete: it takes the earlier run's place (at once, before any slow
        clean-up, so that a finished run is never lost); called again, does nothing."""
        if not self.finished and self.replaces:
            self.folder.replace_with(self.target.path)
        self.finished = True

    def abandon(self) -> str:
        """The run failed or was interrupted: remove what it wrote unless it had finished;
        returns what was done, for the message."""
        path = self.folder.path
        if self.finished:
            return f"kept the finished run {path}"
        if self.replaces:
            shutil.rmtree(self.target.path, ignore_errors=True)
            return f"removed the unfinished run; kept the earlier run in {path}"
        self.folder.clear(keep_folder=True)
        return f"removed the unfinished run {path}"


def _move_all(source: Path, destination: Path) -> None:
    """Move every entry of the folder ``source`` into ``destination`` (``summary.json``
    last: it marks a run finished), merging sub-folders that exist in both."""
    for entry in sorted(source.iterdir(), key=lambda p: p.name == FINISHED):
        there = destination / entry.name
        if entry.is_dir() and there.is_dir():
            _move_all(entry, there)
        else:
            os.replace(entry, there)


def _frozen_normalizer(path: str):
    with open(path, "rb") as handle:
        normalizer = pickle.load(handle)
    normalizer.training = False
    return normalizer


def _loaded(path: Path, what: str, load: Callable, **kwargs):
    """``load(str(path), **kwargs)``; ``ValueError`` naming the file (and ``what`` it was
    loaded as) for whatever the loading raises."""
    try:
        return load(str(path), **kwargs)
    except Exception as exc:
        raise ValueError(f"{path} cannot be loaded{what}: {type(exc).__name__}: {exc}") from None
