"""Export a deployed policy as data: an ONNX graph of the deterministic actor and its
manifest (`elastic_gym.policy.manifest`), the folder `load_policy` reads without
unpickling anything.

For observations x (B, size) float32 the graph computes
z = clip((x - mean) / sqrt(var + eps), -clip_obs, clip_obs) in float64, then float32, with
training's ``VecNormalize`` statistics (the identity when the run did not normalize), and
a = clip(action_net(mlp_actor(features(z))), -1, 1): stable-baselines3's deterministic
action (the Gaussian's mean) clipped as SB3's ``predict`` clips it. A recurrent policy
(sb3-contrib's RecurrentPPO) runs its actor LSTM on z first, its hidden and cell state
explicit inputs and outputs (zeros at an episode's start). A privileged critic's entries
(`elastic_gym.training.critic`) are no input: the actor never reads them. Exported with
PyTorch's TorchScript-based ONNX exporter, opset `OPSET`.
"""

from __future__ import annotations

import contextlib
import datetime
import os
import shutil
import tempfile
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import elastic_gym
from elastic_gym.policy.actors import (
    ACTION,
    CELL,
    CELL_OUT,
    HIDDEN,
    HIDDEN_OUT,
    OBSERVATION,
)
from elastic_gym.policy.builder import build_policy_env
from elastic_gym.policy.loading import sha256
from elastic_gym.policy.manifest import (
    GRAPH_FILE,
    ActionLayout,
    FeatureBlock,
    Graph,
    Manifest,
    ObservationLayout,
    Provenance,
    Tensor,
)
from elastic_gym.policy.spec import PolicySpec

OPSET = 17


@dataclass(frozen=True)
class Normalization:
    """``VecNormalize``'s observation statistics (arrays of the training observation,
    privileged entries included) or ``None`` fields when the run did not normalize."""

    mean: np.ndarray | None = None
    var: np.ndarray | None = None
    epsilon: float = 1e-8
    clip: float = 10.0

    @property
    def active(self) -> bool:
        return self.mean is not None

    def text(self) -> str:
        if not self.active:
            return "none: the graph takes the features as they are"
        return (
            f"inside the graph: clip((x - mean) / sqrt(var + {self.epsilon:g}), "
            f"-{self.clip:g}, {self.clip:g}) with training's VecNormalize statistics"
        )


def _actor_module(policy: Any, normalization: Normalization, size: int):
    """The torch module of the graph (module docstring) around an SB3 policy."""
    import torch

    privileged = int(getattr(policy, "privileged_size", 0))
    recurrent = hasattr(policy, "lstm_actor")

    class Actor(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.policy = policy
            if normalization.active:
                assert normalization.mean is not None and normalization.var is not None
                mean = np.asarray(normalization.mean, dtype=np.float64)[:size]
                scale = np.sqrt(
                    np.asarray(normalization.var, dtype=np.float64) + normalization.epsilon
                )
                self.register_buffer("mean", torch.as_tensor(mean))
                self.register_buffer("scale", torch.as_tensor(scale[:size]))

        def features(self, obs):
            if normalization.active:
                clip = normalization.clip
                obs = ((obs.double() - self.mean) / self.scale).clamp(-clip, clip).float()
            if privileged:  # the actor's extractor slices them off (training.critic)
                obs = torch.cat([obs, torch.zeros(obs.shape[0], privileged)], dim=1)
            return self.policy.pi_features_extractor(obs)

        def act(self, latent):
            mean = self.policy.action_net(self.policy.mlp_extractor.forward_actor(latent))
            return mean.clamp(-1.0, 1.0)

    if not recurrent:

        class Memoryless(Actor):
            def forward(self, obs):
                return self.act(self.features(obs))

        return Memoryless()

    class Recurrent(Actor):
        def forward(self, obs, hidden, cell):
            out, (hidden, cell) = self.policy.lstm_actor(self.features(obs)[None], (hidden, cell))
            return self.act(out[0]), hidden, cell

    return Recurrent()


def export_graph(policy: Any, normalization: Normalization, size: int, path: Path) -> Graph:
    """Write the ONNX graph of an SB3 policy (`_actor_module`) to ``path``; its
    description for the manifest."""
    import torch

    module = _actor_module(policy, normalization, size).eval()
    obs = torch.zeros(1, size)
    n = int(policy.action_space.shape[0])
    lstm = getattr(policy, "lstm_actor", None)
    inputs = [Tensor(name=OBSERVATION, shape=["batch", size], meaning="the policy observation")]
    outputs = [Tensor(name=ACTION, shape=["batch", n], meaning="the action a in [-1, 1]")]
    args: tuple = (obs,)
    axes: dict[str, dict[int, str]] = {OBSERVATION: {0: "batch"}, ACTION: {0: "batch"}}
    if lstm is not None:
        shape: list = [lstm.num_layers, "batch", lstm.hidden_size]
        zeros = torch.zeros(lstm.num_layers, 1, lstm.hidden_size)
        args = (obs, zeros, zeros.clone())
        for name, out_name, what in ((HIDDEN, HIDDEN_OUT, "hidden"), (CELL, CELL_OUT, "cell")):
            start = f"the actor LSTM's {what} state before this step (zeros at an episode's start)"
            inputs.append(Tensor(name=name, shape=shape, meaning=start))
            outputs.append(Tensor(name=out_name, shape=shape, meaning=f"its {what} state after it"))
            axes[name] = axes[out_name] = {1: "batch"}
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the exporter's deprecation and tracer warnings
        torch.onnx.export(
            module,
            args,
            str(path),
            input_names=[t.name for t in inputs],
            output_names=[t.name for t in outputs],
            dynamic_axes=axes,
            opset_version=OPSET,
            dynamo=False,
        )
    return Graph(file=path.name, sha256=sha256(path), opset=OPSET, inputs=inputs, outputs=outputs)


def _wrapper(env: Any, attribute: str) -> Any:
    """The first wrapper down a single-env stack with ``attribute`` in its own fields."""
    while True:
        if attribute in vars(env):
            return vars(env)[attribute]
        env = env.env


def layout(spec: PolicySpec, normalization: Normalization) -> dict[str, Any]:
    """The manifest's observation and action layouts, policy rate and control period of
    ``spec`` (its deployment stack built once on the nominal robot)."""
    env = build_policy_env(spec, spec.make_env())
    try:
        builder, action_map = _wrapper(env, "builder"), _wrapper(env, "map")
        control_dt = float(env.unwrapped.control_dt)
    finally:
        env.close()
    blocks, start = [], 0
    for name, size in builder.sizes.items():
        blocks.append(
            FeatureBlock(name=name, start=start, size=size, meaning=builder.meaning(name))
        )
        start += size
    observation = ObservationLayout(
        size=builder.size * spec.frames,
        frames=spec.frames,
        frame_size=builder.size,
        features=blocks,
        normalization=normalization.text(),
    )
    config = spec.action
    motor_pd = config.kind == "motor-offset"
    action = ActionLayout(
        size=action_map.size,
        kind=config.kind,
        meaning=action_meaning(spec),
        torque_limit=action_map.torque_limit.tolist(),
        kp=action_map.kp.tolist() if motor_pd else None,
        kd=action_map.kd.tolist() if motor_pd else None,
    )
    rate = 1.0 / (spec.decimation * control_dt)
    return {
        "observation": observation,
        "action": action,
        "policy_rate": rate,
        "control_dt": control_dt,
    }


def action_meaning(spec: PolicySpec) -> str:
    """The action's meaning in words (`elastic_gym.policy.actions`), held for
    ``decimation`` control periods."""
    c = spec.action
    held = f"held for {spec.decimation} control period(s); at every period "
    if c.kind == "torque":
        return held + "the motor torque is tau = torque_limit * a"
    if c.kind == "motor-offset":
        gravity = " + g(q_d) of the nominal model" if c.gravity_compensation else ""
        return held + (
            f"a motor PD tracks q_d + {c.offset_scale:g} a: tau = kp (q_d + {c.offset_scale:g} a "
            f"- theta) + kd (q_d' - theta'){gravity}"
        )
    if c.on_link_masses:
        return held + (
            f"the residual base {c.residual!r} runs on link masses scaled by s = 1 + "
            f"{c.residual_scale:g} rho(a) (deadzone {c.residual_deadzone:g})"
        )
    return held + (
        f"tau = tau_base + {c.residual_scale:g} torque_limit rho(a), tau_base of the base "
        f"controller {c.residual!r}, rho a deadzone of width {c.residual_deadzone:g}"
    )


def export_policy(
    spec: PolicySpec,
    policy: Any,
    normalization: Normalization,
    provenance: Mapping[str, Any],
    output: str | os.PathLike,
    overwrite: bool = False,
) -> Manifest:
    """Write the exported policy folder ``output``: ``policy.onnx`` and ``policy.json``.

    Args:
        spec: the policy's spec.
        policy: the SB3 policy (``model.policy``) whose actor is exported.
        normalization: its observation statistics.
        provenance: the manifest's provenance fields but the export's own.
        output: the folder (refused if it holds files, unless ``overwrite``).

    The folder is written beside its target and moved into place at the end: an export
    that fails leaves the earlier folder (or none).
    """
    target = Path(output)
    if target.exists() and not target.is_dir():
        raise NotADirectoryError(f"--output {target} is a file")
    if target.is_dir() and any(target.iterdir()) and not overwrite:
        raise FileExistsError(f"--output {target} holds files; give --overwrite to replace them")
    parts = layout(spec, Normalization() if not normalization.active else normalization)
    size = parts["observation"].size
    made = {
        **provenance,
        "exported_with": elastic_gym.__version__,
        "exported_on": datetime.date.today().isoformat(),
    }
    target.parent.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.parent))
    umask = os.umask(0)
    os.umask(umask)
    scratch.chmod(0o777 & ~umask)  # a folder as mkdir makes it, not mkdtemp's private one
    try:
        graph = export_graph(policy, normalization, size, scratch / GRAPH_FILE)
        manifest = Manifest(
            env_id=spec.env_id,
            state=spec.state,
            spec=spec,
            graph=graph,
            provenance=Provenance(**made),
            **parts,
        )
        manifest.write(scratch)
        if target.exists():
            old = target.with_name(f".{target.name}.old")
            os.replace(target, old)
            os.replace(scratch, target)
            shutil.rmtree(old)
        else:
            os.replace(scratch, target)
    except BaseException:
        with contextlib.suppress(OSError):
            shutil.rmtree(scratch)
        raise
    return manifest
