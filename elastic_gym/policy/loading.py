"""Loading a policy: an exported policy folder (data only), or a training run folder
(pickles: only when the user says they trust it).

* An **exported policy** (`elastic-gym export`; ``policy.onnx`` + ``policy.json``) loads
  as its manifest's spec and an [`OnnxActor`][elastic_gym.policy.actors.OnnxActor]: JSON
  and an ONNX graph, checked against the manifest's SHA-256, run by onnxruntime. Nothing
  in the folder is executed.
* A **training run folder** (``model.zip``, ``vecnormalize.pkl``, ``config.yaml``) holds
  pickles: unpickling runs code stored in the files. It is loaded only with
  ``trust_pickle=True`` (the command line's ``--trust-pickle``), by the training package
  (named here by the string `TRUSTED_RUN_LOADER`, imported when needed: the policy package
  sits below training). Without it the loading refuses before it opens a pickle, and
  names `elastic-gym export`.
"""

from __future__ import annotations

import hashlib
import importlib
import os
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from elastic_gym.policy.actors import Actor, OnnxActor
from elastic_gym.policy.manifest import GRAPH_FILE, MANIFEST_FILE, Manifest, read_manifest
from elastic_gym.policy.spec import PolicySpec
from elastic_gym.validation import lookup

# "module:function" of the training package: (folder, best) -> Policy of a run folder,
# and folder -> PolicySpec of a run folder (its config.yaml only, no pickle)
TRUSTED_RUN_LOADER = "elastic_gym.training.trained:run_policy"
RUN_SPEC_READER = "elastic_gym.training.trained:run_spec"
RUN_FILE = "config.yaml"  # what makes a folder a training run folder
TRUST_HELP = "unpickling runs code stored in the files; only for run folders you made or trust"


class UntrustedPickleError(ValueError):
    """A pickle would be loaded without the user saying they trust it."""


@dataclass(frozen=True)
class Policy:
    """A deployed policy: its spec and its actor.

    Attributes:
        spec: what it sees and what its actions mean.
        actor: its act (with the observation normalization).
        source: where it was loaded from (a folder), for messages.
        spec_file, actor_file: the files the spec and the actor came from, for messages.
        manifest: an exported policy's manifest (None for others).
    """

    spec: PolicySpec
    actor: Actor
    source: str = "the policy"
    spec_file: str = "its spec"
    actor_file: str = "its actor"
    manifest: Manifest | None = None


def is_exported(folder: str | Path) -> bool:
    """True when ``folder`` holds an exported policy's manifest."""
    return (Path(folder) / MANIFEST_FILE).is_file()


def is_run_folder(folder: str | Path) -> bool:
    """True when ``folder`` holds a training run's ``config.yaml``."""
    return (Path(folder) / RUN_FILE).is_file()


def _training(target: str):
    module, _, name = target.partition(":")
    try:
        return getattr(importlib.import_module(module), name)
    except ImportError as exc:  # pragma: no cover - the rl extra is missing
        raise ImportError(
            f"loading a training run folder needs the 'rl' extra ({exc}); an exported "
            "policy needs onnxruntime only"
        ) from None


def untrusted(folder: str | Path) -> UntrustedPickleError:
    """The refusal of a run folder loaded without ``trust_pickle``."""
    return UntrustedPickleError(
        f"{folder} is a stable-baselines3 run folder: loading it unpickles model.zip and "
        "vecnormalize.pkl, which runs code stored in the files. Export it to a policy "
        f"without pickles (elastic-gym export {folder}), or, for a run folder you made or "
        "trust, load it with trust_pickle (--trust-pickle)"
    )


def load_policy(folder: str | Path, trust_pickle: bool = False, best: bool = False) -> Policy:
    """The policy in ``folder`` (module docstring): an exported policy, or with
    ``trust_pickle`` a training run folder (``best``: its learning curve's best model).

    Raises `UntrustedPickleError` (a ``ValueError``) for a run folder without
    ``trust_pickle``, before any file of it is opened but ``config.yaml``; ``ValueError``
    naming the file for a folder that is neither, or a file that does not load.
    """
    path = Path(folder)
    if is_exported(path):
        if best:
            raise ValueError(f"{path}: best: an exported policy holds one policy")
        return load_exported(path)
    if not is_run_folder(path):
        why = "no such folder" if not path.is_dir() else f"no {MANIFEST_FILE} nor {RUN_FILE}"
        raise ValueError(
            f"{path} is neither an exported policy (elastic-gym export) nor a training run "
            f"folder: {why}"
        )
    if not trust_pickle:
        raise untrusted(path)
    policy: Policy = _training(TRUSTED_RUN_LOADER)(path, best)
    return policy


def read_spec(folder: str | Path) -> PolicySpec:
    """The spec of the policy in ``folder`` without loading its actor: an exported
    policy's manifest, or a run folder's ``config.yaml`` (no pickle either way)."""
    path = Path(folder)
    if is_exported(path):
        return read_manifest(path).spec
    if is_run_folder(path):
        spec: PolicySpec = _training(RUN_SPEC_READER)(path)
        return spec
    why = "no such folder" if not path.is_dir() else f"no {MANIFEST_FILE} nor {RUN_FILE}"
    raise ValueError(
        f"{path} is neither an exported policy (elastic-gym export) nor a training run "
        f"folder: {why}"
    )


def sha256(path: str | Path) -> str:
    """The SHA-256 of a file, hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def load_exported(folder: str | Path) -> Policy:
    """An exported policy: its manifest (checked) and its graph (checked against the
    manifest's SHA-256 and observation and action sizes), run by onnxruntime."""
    path = Path(folder)
    manifest = read_manifest(path)
    graph = path / manifest.graph.file
    if Path(manifest.graph.file).name != manifest.graph.file or not graph.is_file():
        raise ValueError(
            f"{path / MANIFEST_FILE}: graph.file {manifest.graph.file!r} is no file of the folder"
        )
    if sha256(graph) != manifest.graph.sha256:
        raise ValueError(
            f"{graph}: its SHA-256 is not the manifest's graph.sha256: the file was changed "
            "after the export"
        )
    actor = OnnxActor(graph)
    sizes = {
        "observation.size": (actor.observation_size, manifest.observation.size),
        "action.size": (actor.action_size, manifest.action.size),
    }
    for field, (graph_size, stated) in sizes.items():
        if graph_size != stated:
            raise ValueError(
                f"{path / MANIFEST_FILE}: {field} is {stated}, the graph's is {graph_size}"
            )
    return Policy(
        spec=manifest.spec,
        actor=actor,
        source=str(path),
        spec_file=MANIFEST_FILE,
        actor_file=GRAPH_FILE,
        manifest=manifest,
    )


# ---------------------------------------------------------------- callable policies' files
def load_sb3_model(path: str | os.PathLike, algorithm: str | type, trust_pickle: bool):
    """A saved stable-baselines3 model (``algorithm`` a class or its name); its file holds
    pickled objects, so ``trust_pickle`` must be given."""
    if not trust_pickle:
        raise UntrustedPickleError(
            f"policy {os.fspath(path)}: a saved stable-baselines3 model holds pickled "
            f"objects ({TRUST_HELP}): give trust_pickle, or export the run (elastic-gym export)"
        )
    if isinstance(algorithm, str):
        try:
            sb3 = importlib.import_module("stable_baselines3")
        except ImportError as exc:  # pragma: no cover - optional dependency
            raise ImportError("loading a policy file needs stable-baselines3 (extra 'rl')") from exc
        base = importlib.import_module("stable_baselines3.common.base_class").BaseAlgorithm
        algorithms = {
            name: cls
            for name, cls in vars(sb3).items()
            if isinstance(cls, type) and issubclass(cls, base)
        }
        algorithm = lookup(algorithms, algorithm, "stable-baselines3 algorithm")
    cls: Any = algorithm
    return cls.load(os.fspath(path), device="cpu")


def load_normalization(normalization: Any, trust_pickle: bool):
    """A ``VecNormalize``-like object (with ``normalize_obs``) from an object, or from the
    path of its pickle with ``trust_pickle``; frozen (``training`` off)."""
    if normalization is None:
        return None
    if isinstance(normalization, (str, os.PathLike)):
        if not trust_pickle:
            raise UntrustedPickleError(
                f"normalization {os.fspath(normalization)}: a pickle ({TRUST_HELP}): give "
                "trust_pickle"
            )
        with open(normalization, "rb") as handle:
            normalization = pickle.load(handle)  # trusted by the caller
    if not callable(getattr(normalization, "normalize_obs", None)):
        raise TypeError(
            "normalization must be a VecNormalize (with normalize_obs) or the path of its pickle, "
            f"got {type(normalization).__name__}"
        )
    normalization.training = False
    return normalization
