"""The folder of one training run: created, refused or overwritten, removed on failure,
loaded back, and old folders migrated.

A run folder holds ``model.zip``, ``vecnormalize.pkl``, ``best_model.zip``, ``config.yaml``,
``summary.json`` (written last: a folder with it holds a finished run), ``evaluations.npz``,
``learning_curve.csv`` and ``tb/``. A folder holding a run is refused unless ``overwrite``,
which removes that run's files and only those. A run that fails or is interrupted removes
what it wrote (:meth:`RunFolder.create`). ``config.yaml`` is self-contained; a folder of an
earlier release is migrated when read (:data:`MIGRATIONS`), so that new defaults never change
what a saved policy's actions mean. ``model.zip`` and ``vecnormalize.pkl`` are pickles: load
only run folders from trusted sources.
"""

from __future__ import annotations

import contextlib
import json
import pickle
import shutil
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import yaml

from elastic_gym.runtime.folder_lock import check_free, check_writable, folder_lock
from elastic_gym.schemas import schema_comment
from elastic_gym.training.config import TrainConfig, algorithm_class
from elastic_gym.yaml_io import load_yaml

RUN_FILES = ("model.zip", "vecnormalize.pkl", "config.yaml")  # needed to load a run
CURVE_FILE = "learning_curve.csv"  # the learning curve (elastic_gym.training.learning_curve)
FINISHED = "summary.json"
RUN_OUTPUTS = (*RUN_FILES, "best_model.zip", FINISHED, "evaluations.npz", CURVE_FILE, "tb")


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

    def check(self, overwrite: bool = False) -> None:
        """Raise if the folder cannot receive a run (changes nothing): ``NotADirectoryError``
        if it is a file, ``PermissionError`` if it cannot be written (a read-only file
        system, :func:`~elastic_gym.runtime.folder_lock.check_writable`), ``FileExistsError`` if it
        holds an earlier run and not ``overwrite``."""
        check_free(self.path, self.earlier_run, "an earlier run", "--out", overwrite)

    def lock(self) -> contextlib.AbstractContextManager:
        """The folder's writer lock for a ``with`` block
        (:func:`~elastic_gym.runtime.folder_lock.folder_lock`: another writer is refused with
        :class:`~elastic_gym.runtime.folder_lock.FolderLockedError`); checked writable first."""
        check_writable(self.path)
        return folder_lock(self.path)

    @contextlib.contextmanager
    def create(self, overwrite: bool = False, lock: bool = True) -> Iterator[RunFolder]:
        """The folder, ready to receive a run, for the ``with`` block that writes it.

        Under the folder's writer lock (:meth:`lock`; ``lock=False``: the caller holds
        it), checked (:meth:`check`); with ``overwrite`` the earlier run's files are
        removed. If the block raises or is interrupted, what the run wrote is removed,
        and the folders made for it if left empty; a ``KeyboardInterrupt`` becomes
        :class:`~elastic_gym.runtime.parallel.Interrupted` saying so.
        """
        from elastic_gym.runtime.parallel import Interrupted

        with self.lock() if lock else contextlib.nullcontext():
            self.check(overwrite)
            created = missing_folders(self.path)
            if overwrite:
                self.clear(keep_folder=True)
            self.path.mkdir(parents=True, exist_ok=True)
            try:
                yield self
            except BaseException as exc:
                self.clear(keep_folder=True)
                remove_empty(created)
                if isinstance(exc, KeyboardInterrupt):
                    raise Interrupted.of(exc, f"removed the unfinished run {self.path}") from None
                raise

    def clear(self, keep_folder: bool = False) -> None:
        """Remove the files of a run (and of ``seed*`` sub-runs) from the folder, and the
        folders left empty (the folder itself too unless ``keep_folder``); nothing else."""
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
            if not (keep_folder and directory == self.path):
                remove_empty([directory])

    # ------------------------------------------------------------------ files
    def write_config(self, config: TrainConfig) -> None:
        """``config.yaml``: the config as the run used it (self-contained: no pointer to
        a hyper-parameter file, every field of the action and observation configs), its
        first line naming the ``run`` schema (:func:`~elastic_gym.schemas.schema_comment`)."""
        text = schema_comment("run") + yaml.safe_dump(config.to_dict(), sort_keys=False)
        (self.path / "config.yaml").write_text(text)

    def write_summary(self, summary: dict) -> None:
        """``summary.json``: written last, it marks the run finished."""
        (self.path / FINISHED).write_text(json.dumps(summary, indent=2))

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
