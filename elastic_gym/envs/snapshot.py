"""Pickling a batch: a snapshot of every part's state, restored into a new batch.

A PyBullet client cannot be pickled, so a pickled batch is its constructor's arguments and
a snapshot of the state of its parts, each taken and restored by the part itself: the
simulator's (theta, q, theta', q'), the episode arrays
([`EpisodeState`][elastic_gym.envs.episode.EpisodeState]), every arm's generator, the
plants ([`PlantState`][elastic_gym.envs.plant_state.PlantState]: drawn settings, payloads,
pulses, plant streams), the sensors' noise blocks, biases and filters, and the task's
episodes. Unpickling builds an independent batch with its own client and restores the
snapshot into it: it continues bit for bit like the original.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from elastic_gym.envs.episode import EpisodeState
from elastic_gym.envs.measurement import Sensors
from elastic_gym.envs.plant_state import PlantState
from elastic_gym.envs.simulator import ArmSimulator
from elastic_gym.envs.task_base import Task


@dataclass(frozen=True)
class Parts:
    """The parts of a batch whose state a snapshot holds (``rngs``: every arm's generator)."""

    sim: ArmSimulator
    episode: EpisodeState
    plant_state: PlantState
    sensors: Sensors
    task: Task
    rngs: list[np.random.Generator]


def capture(parts: Parts) -> dict:
    """A snapshot of the state of ``parts`` (plain data and arrays, picklable)."""
    sim = parts.sim
    return {
        "sim": (sim.q.copy(), sim.dq.copy(), sim.theta.copy(), sim.dtheta.copy()),
        "substeps": None if sim.rk4 is None else sim.rk4.substeps.copy(),
        "episode": parts.episode.snapshot(),
        "rngs": [rng.bit_generator.state for rng in parts.rngs],
        "plants": parts.plant_state.snapshot(),
        "sensors": parts.sensors.snapshot(),
        "task": parts.task.snapshot(),
    }


def restore(parts: Parts, snapshot: dict) -> None:
    """The state of a `capture` of a batch made with the same arguments, into ``parts``:
    the simulator's state, the episode, the generators' states, then the plants (their
    streams follow the restored generators), the sensors and the task."""
    parts.sim.reset_state(np.arange(len(parts.rngs)), *snapshot["sim"])
    if parts.sim.rk4 is not None:  # each arm's substeps of its next period
        parts.sim.rk4.substeps[:] = snapshot["substeps"]
    parts.episode.restore(snapshot["episode"])
    for rng, state in zip(parts.rngs, snapshot["rngs"], strict=True):
        rng.bit_generator.state = state
    parts.plant_state.restore(snapshot["plants"], parts.rngs)
    parts.sensors.restore(snapshot["sensors"])
    parts.task.restore(snapshot["task"])
