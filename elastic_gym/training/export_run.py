"""A training run folder read for `elastic-gym export` without running code from it.

A run folder's ``model.zip`` and ``vecnormalize.pkl`` are pickles (SB3 keeps cloudpickled
objects in the zip's ``data``); loading them the usual way runs whatever code they carry.
The export reads what it needs as data only:

* the policy's architecture from ``config.yaml`` (YAML, validated: algorithm, policy and
  ``policy_kwargs`` of its hyper-parameters) and the observation and action sizes of its
  spec, so SB3's policy class is built here, not unpickled;
* the weights from the zip's ``policy.pth`` with ``torch.load(weights_only=True)`` (tensors
  only; the zip's pickled ``data`` is never read);
* the normalization statistics from ``vecnormalize.pkl`` with a restricted unpickler
  (`read_normalization`): numpy arrays are rebuilt, ``VecNormalize`` and its
  ``RunningMeanStd`` become inert records of their fields, and any other global a pickle
  names (a function to call, a class to build) is refused before it is looked up.
"""

from __future__ import annotations

import hashlib
import io
import json
import pickle
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from elastic_gym.policy.builder import build_policy_env
from elastic_gym.policy.export import Normalization, export_policy
from elastic_gym.policy.manifest import Manifest
from elastic_gym.policy.spec import PolicySpec
from elastic_gym.training.config import algorithm_class, default_policy
from elastic_gym.training.run_folder import FINISHED, RunFolder

EXPORTABLE = ("ppo", "recurrentppo")  # an actor of mlp_extractor + action_net (+ LSTM)


class _Record:
    """An inert stand-in for a pickled object: its state kept as a dict, nothing run."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args = args

    def __setstate__(self, state: Any) -> None:
        self.state = state


def _inert(*args: Any, **kwargs: Any) -> _Record:
    return _Record(*args)


NUMPY = {  # the globals numpy's own array pickles name (data only)
    ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "scalar"),
    ("numpy.core.multiarray", "scalar"),
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
}
RECORDS = {  # classes whose fields we read, and what else a VecNormalize pickle names
    ("stable_baselines3.common.vec_env.vec_normalize", "VecNormalize"),
    ("stable_baselines3.common.running_mean_std", "RunningMeanStd"),
    ("gymnasium.spaces.box", "Box"),
    ("gymnasium.spaces.dict", "Dict"),
    ("numpy.random._pickle", "__generator_ctor"),
    ("numpy.random._pickle", "__bit_generator_ctor"),
    ("numpy.random._pickle", "__randomstate_ctor"),
    ("numpy.random._pcg64", "PCG64"),
    ("numpy.random.bit_generator", "SeedSequence"),
    ("numpy.random.bit_generator", "__pyx_unpickle_SeedSequence"),
}


class _StatisticsUnpickler(pickle.Unpickler):
    """Unpickles numpy arrays and records (module docstring); refuses everything else."""

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in NUMPY:
            return super().find_class(module, name)
        if (module, name) in RECORDS:
            return _inert if name.startswith("__") else _Record
        raise pickle.UnpicklingError(
            f"it names {module}.{name}, which is no part of VecNormalize statistics "
            "(refused: unpickling it could run code)"
        )


def read_normalization(path: str | Path) -> Normalization:
    """The observation statistics of a ``vecnormalize.pkl`` (module docstring);
    ``ValueError`` naming the file for anything else."""
    path = Path(path)
    try:
        with open(path, "rb") as handle:
            record = _StatisticsUnpickler(handle).load()
        state = record.state if isinstance(record, _Record) else None
        if not isinstance(state, dict):
            raise pickle.UnpicklingError("it holds no VecNormalize")
        if not state.get("norm_obs", True):
            return Normalization()
        stats = state["obs_rms"].state
        mean, var = (np.asarray(stats[key], dtype=np.float64) for key in ("mean", "var"))
        if mean.ndim != 1 or mean.shape != var.shape or not np.all(np.isfinite(mean + var)):
            raise pickle.UnpicklingError(f"its statistics have shapes {mean.shape}, {var.shape}")
        return Normalization(
            mean=mean, var=var, epsilon=float(state["epsilon"]), clip=float(state["clip_obs"])
        )
    except (pickle.UnpicklingError, AttributeError, KeyError, TypeError, EOFError) as exc:
        raise ValueError(f"{path} is not a VecNormalize statistics file: {exc}") from None


def read_weights(path: Path) -> dict[str, Any]:
    """The policy's state dict from an SB3 ``model.zip`` (its ``policy.pth``), tensors
    only (``weights_only``); ``ValueError`` naming the file."""
    import torch

    try:
        with zipfile.ZipFile(path) as archive:
            data = archive.read("policy.pth")
        return torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except (OSError, KeyError, zipfile.BadZipFile, pickle.UnpicklingError, RuntimeError) as exc:
        raise ValueError(f"{path} holds no SB3 policy weights: {exc}") from None


@dataclass(frozen=True)
class RunExport:
    """What an export takes from a run folder: the spec, the SB3 policy with its weights,
    the normalization and the provenance."""

    spec: PolicySpec
    policy: Any
    normalization: Normalization
    provenance: dict[str, Any]


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def read_run(folder: str | Path, best: bool = False) -> RunExport:
    """The run in ``folder`` as data (module docstring); ``best``: its learning curve's
    best model. ``ValueError`` naming the file for a folder that is no run of an
    exportable algorithm (``ppo``, ``recurrentppo``) or whose files do not fit."""
    run = RunFolder(folder)
    config = run.read_config()
    if config.algo not in EXPORTABLE:
        raise ValueError(
            f"{run.path}: an {config.algo} policy; export takes {' or '.join(EXPORTABLE)} "
            "(an actor of mlp_extractor and action_net)"
        )
    settings, algo_kwargs = config.settings()
    spec = config.policy_spec(settings)
    model_file = run.path / "best_model.zip" if best else run.path / "model.zip"
    if not model_file.is_file():
        raise ValueError(f"{model_file}: no such file (best: the learning curve's best model)")
    policy = _policy(config.algo, algo_kwargs, spec)
    try:
        policy.load_state_dict(read_weights(model_file))
    except RuntimeError as exc:
        raise ValueError(
            f"{model_file}: its weights do not fit the policy config.yaml describes: "
            f"{' '.join(str(exc).split())}"
        ) from None
    policy.set_training_mode(False)
    normalization = read_normalization(run.path / "vecnormalize.pkl")
    entries = int(policy.observation_space.shape[0])
    mean = normalization.mean
    if mean is not None and mean.size != entries:
        raise ValueError(
            f"{run.path / 'vecnormalize.pkl'}: statistics of {mean.size} entries, "
            f"but the policy takes {entries}: the files are of different runs"
        )
    return RunExport(spec, policy, normalization, _provenance(run, config, model_file))


def _policy(algo: str, algo_kwargs: dict, spec: PolicySpec) -> Any:
    """SB3's policy of the run, built from its hyper-parameters with fresh weights, on
    the spaces of its training stack (the privileged critic's entries included)."""
    env = build_policy_env(spec, spec.make_env(), critic=True)
    try:
        observation_space, action_space = env.observation_space, env.action_space
    finally:
        env.close()
    kwargs = dict(algo_kwargs.get("policy_kwargs") or {})
    cls = algorithm_class(algo)
    if spec.critic:
        from gymnasium.spaces import flatdim

        from elastic_gym.training.critic import PrivilegedCriticPolicy

        deployed = build_policy_env(spec, spec.make_env())
        try:
            kwargs["privileged_size"] = flatdim(observation_space) - flatdim(
                deployed.observation_space
            )
        finally:
            deployed.close()
        policy_class: Any = PrivilegedCriticPolicy
    else:
        policy_class = cls.policy_aliases[algo_kwargs.get("policy", default_policy(algo))]
    use_sde = bool(algo_kwargs.get("use_sde", False))
    return policy_class(observation_space, action_space, lambda _: 0.0, use_sde=use_sde, **kwargs)


def _provenance(run: RunFolder, config: Any, model_file: Path) -> dict[str, Any]:
    summary: dict[str, Any] = {}
    if (run.path / FINISHED).is_file():
        try:
            summary = json.loads((run.path / FINISHED).read_text())
        except ValueError:
            summary = {}
    files = [model_file, run.path / "vecnormalize.pkl", run.path / "config.yaml"]
    return {
        "run": run.path.resolve().name,
        "algo": config.algo,
        "seed": config.seed,
        "policy_steps": summary.get("policy_steps"),
        "env_steps": summary.get("env_steps"),
        "hyperparams": dict(config.hyperparams),
        "run_files": {path.name: _digest(path) for path in files},
    }


def export_run(
    folder: str | Path,
    output: str | Path | None = None,
    best: bool = False,
    overwrite: bool = False,
) -> Manifest:
    """`elastic-gym export` in Python: the run in ``folder`` (read as data, `read_run`)
    written as an exported policy to ``output`` (default: ``<folder>-export`` beside it);
    returns its manifest."""
    run = Path(folder)
    target = Path(output) if output is not None else run.with_name(f"{run.name}-export")
    exported = read_run(run, best=best)
    return export_policy(
        exported.spec,
        exported.policy,
        exported.normalization,
        exported.provenance,
        target,
        overwrite=overwrite,
    )
