"""The manifest of an exported policy (``policy.json`` beside ``policy.onnx``): what each
input and output of the graph is, for a user who runs the graph outside elastic-gym.

``policy.onnx`` holds the deterministic actor with training's observation normalization
and the clipping of the action to [-1, 1] inside it (a recurrent policy's LSTM state as
explicit inputs and outputs, `elastic_gym.policy.export`). ``policy.json`` holds the
policy's [`PolicySpec`][elastic_gym.policy.spec.PolicySpec], the observation layout (each
feature block: where it starts, its size and meaning), the action's meaning (kind, torque
limits, motor PD gains), the policy rate, the graph's inputs and outputs with its
SHA-256, and where the policy comes from (the training run, its algorithm, seed, steps,
hyper-parameters and the SHA-256 of its files). Its JSON Schema ships as
``elastic_gym/schemas/policy.json`` (``elastic-gym schema policy``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, StrictInt, StrictStr, model_validator

from elastic_gym.policy.spec import PolicySpec
from elastic_gym.validation import Finite, PositiveFinite, StrictModel, validated

FORMAT = 1
GRAPH_FILE = "policy.onnx"
MANIFEST_FILE = "policy.json"
Count = Annotated[StrictInt, Field(ge=1)]
Index = Annotated[StrictInt, Field(ge=0)]
Sha256 = Annotated[StrictStr, Field(pattern=r"^[0-9a-f]{64}$")]


class FeatureBlock(StrictModel):
    """One feature of a frame: entries ``start`` .. ``start + size - 1``."""

    name: StrictStr
    start: Index
    size: Count
    meaning: StrictStr


class ObservationLayout(StrictModel):
    """The graph's ``observation`` input: ``frames`` frames of ``frame_size`` entries,
    oldest first (after a reset every frame is the first one), each frame the feature
    blocks in order; ``normalization`` says what the graph does to it first."""

    size: Count
    frames: Count
    frame_size: Count
    features: list[FeatureBlock] = Field(min_length=1)
    normalization: StrictStr

    @model_validator(mode="after")
    def _contiguous(self) -> ObservationLayout:
        start = 0
        for block in self.features:
            if block.start != start:
                raise ValueError(f"feature {block.name!r} starts at {block.start}, not {start}")
            start += block.size
        if start != self.frame_size or self.size != self.frames * self.frame_size:
            raise ValueError(
                f"the features fill {start} entries of a frame of {self.frame_size}, and "
                f"{self.frames} frames of it are not the observation's {self.size}"
            )
        return self


class ActionLayout(StrictModel):
    """The graph's ``action`` output a in [-1, 1]^size and the torque it means (the
    ``meaning`` in words, with the nominal model's ``torque_limit`` and, for
    ``motor-offset``, the motor PD gains ``kp``, ``kd``)."""

    size: Count
    kind: StrictStr
    meaning: StrictStr
    torque_limit: list[Finite] = Field(min_length=1)
    kp: list[Finite] | None = None
    kd: list[Finite] | None = None


class Tensor(StrictModel):
    """An input or output of the graph (float32; ``"batch"`` is the free axis)."""

    name: StrictStr
    shape: list[Count | Literal["batch"]]
    meaning: StrictStr


class Graph(StrictModel):
    """The ONNX file, its SHA-256 and opset, its inputs and outputs."""

    file: StrictStr = GRAPH_FILE
    sha256: Sha256
    opset: Count
    inputs: list[Tensor] = Field(min_length=1)
    outputs: list[Tensor] = Field(min_length=1)


class Provenance(StrictModel):
    """Where the policy comes from: its training run and the export."""

    run: StrictStr  # the run folder's name
    algo: StrictStr
    seed: Index
    policy_steps: Index | None = None
    env_steps: Index | None = None
    hyperparams: dict[str, Any] = Field(default_factory=dict)
    run_files: dict[str, Sha256] = Field(default_factory=dict)  # name -> SHA-256
    exported_with: StrictStr  # elastic-gym version
    exported_on: StrictStr  # ISO date


class Manifest(StrictModel):
    """``policy.json`` of an exported policy (module docstring)."""

    format: Literal[1] = 1  # FORMAT
    env_id: StrictStr
    state: StrictStr
    policy_rate: PositiveFinite  # Hz
    control_dt: PositiveFinite  # s
    spec: PolicySpec
    observation: ObservationLayout
    action: ActionLayout
    graph: Graph
    provenance: Provenance

    @model_validator(mode="after")
    def _consistent(self) -> Manifest:
        if (self.env_id, self.state) != (self.spec.env_id, self.spec.state):
            raise ValueError(
                f"env_id and state ({self.env_id}, {self.state!r}) are not the spec's "
                f"({self.spec.env_id}, {self.spec.state!r})"
            )
        if self.observation.frames != self.spec.frames:
            raise ValueError(
                f"observation.frames {self.observation.frames} is not the spec's {self.spec.frames}"
            )
        return self

    def write(self, folder: Path) -> Path:
        """``policy.json`` in ``folder`` (plain JSON, keys in the models' order)."""
        path = Path(folder) / MANIFEST_FILE
        path.write_text(json.dumps(self.model_dump(mode="json"), indent=2) + "\n")
        return path


def read_manifest(folder: str | Path) -> Manifest:
    """The manifest of an exported policy folder; a missing, unreadable or invalid file
    raises ``ValueError`` naming it and the field."""
    path = Path(folder) / MANIFEST_FILE
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable manifest: {exc}") from None
    try:
        return validated(Manifest, data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
