"""Groups of runs that share one world: the batches a comparison runs (part of its plan).

Runs share a world (one vector env of N arms, one vector observer, one vector controller)
when everything the world is built from is equal: env id and its kwargs other than the
per-arm ones, reset options, duration, controller class and options, state source and
model error. Seeds and the per-arm plant kwargs
(`elastic_gym.envs.config.PER_ARM_KEYS`) vary per arm through the env's ``per_arm``
kwarg: arm i is bit for bit the single env made with run i's kwargs and seed, so a grouped
run gives the row it gives alone.

[`plan_groups`][elastic_gym.evaluation.groups.plan_groups] keeps the first-seen order, cuts
each group into batches of at most ``batch_size`` arms of nearly equal size, and splits the
largest further while there are fewer than two batches per worker.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass

from elastic_gym.envs.config import PER_ARM_KEYS
from elastic_gym.evaluation.grid import RunSpec
from elastic_gym.validation import plain

DEFAULT_BATCH_SIZE = 64  # arms per world
BATCHES_PER_WORKER = 2  # fewest batches per worker before batches are cut smaller


@dataclass(frozen=True)
class RunGroup:
    """Runs (in run order) that share one world; see the module docstring."""

    runs: tuple[RunSpec, ...]

    def __len__(self) -> int:
        return len(self.runs)

    @property
    def first(self) -> RunSpec:
        return self.runs[0]

    @property
    def shared_kwargs(self) -> dict:
        """The env kwargs of every arm (the first run's, less the per-arm ones)."""
        return {k: v for k, v in self.first.env_kwargs.items() if k not in PER_ARM_KEYS}

    def per_arm(self) -> list[dict] | None:
        """Each run's per-arm kwargs (the env's ``per_arm``), None when all arms agree."""
        own = [{k: v for k, v in r.env_kwargs.items() if k in PER_ARM_KEYS} for r in self.runs]
        return None if all(o == own[0] for o in own) else own

    def env_kwargs(self) -> dict:
        """The kwargs of the vector env: shared kwargs, and ``per_arm`` when arms differ
        (else the per-arm kwargs the arms share)."""
        per_arm = self.per_arm()
        if per_arm is None:
            return dict(self.first.env_kwargs)
        return {**self.shared_kwargs, "per_arm": per_arm}

    @property
    def seeds(self) -> list[int]:
        return [r.seed for r in self.runs]


def _class_key(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def group_key(spec: RunSpec) -> str:
    """Everything that must be equal for runs to share a world (module docstring)."""
    shared = {k: v for k, v in spec.env_kwargs.items() if k not in PER_ARM_KEYS}
    controller, source = spec.controller, spec.source
    return json.dumps(
        plain(
            [
                spec.env_id,
                shared,
                spec.reset_options,
                spec.duration,
                _class_key(spec.controller_cls),
                controller.options,
                _class_key(spec.observer_cls),
                source.name,
                source.options,
                source.initial_estimate,
                spec.model_error,
                spec.model_file,
            ]
        ),
        sort_keys=True,
        default=repr,  # classes and callables in options: the same object, the same text
    )


def _split(runs: Sequence[RunSpec], parts: int) -> list[tuple[RunSpec, ...]]:
    """``runs`` cut into ``parts`` consecutive pieces whose sizes differ by at most one."""
    size, extra = divmod(len(runs), parts)
    out, start = [], 0
    for k in range(parts):
        stop = start + size + (k < extra)
        out.append(tuple(runs[start:stop]))
        start = stop
    return out


def plan_groups(
    runs: Sequence[RunSpec], batch_size: int = DEFAULT_BATCH_SIZE, workers: int = 1
) -> list[RunGroup]:
    """The batches of ``runs`` (module docstring); every run is in exactly one."""
    grouped: dict[str, list[RunSpec]] = {}
    for spec in runs:
        grouped.setdefault(group_key(spec), []).append(spec)
    batches = [
        piece
        for members in grouped.values()
        for piece in _split(members, math.ceil(len(members) / batch_size))
    ]
    while len(batches) < BATCHES_PER_WORKER * workers:
        largest = max(range(len(batches)), key=lambda k: len(batches[k]))
        if len(batches[largest]) < 2:
            break
        batches[largest : largest + 1] = _split(batches[largest], 2)
    return [RunGroup(piece) for piece in batches]
