"""A control period in compiled calls equals the step by step path.

`post_step_kernel` of `elastic_gym.envs.kernels` runs the kernels that
``ArmBatch.step`` otherwise calls one by one (transmission + forward dynamics +
accelerometer readings, termination codes, shared sensor error model, sensor delay line,
observation, reward). Batches of every id, with sensor noise and delays and with arms
breaking their physics, must give bit for bit the same observations, rewards,
terminations and info as the same batch forced onto the step by step path. So must
`control_period_kernel` (the clip to the reference in
one call) against a task without compiled form, stepped call by call.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from helpers import fast_lane, leaves

import elastic_gym
from elastic_gym.envs.packing import FusedArguments
from elastic_gym.envs.tasks import TASKS

KWARGS = {
    "elastic_gym/TwoLinkElastic-v0": {
        "sensor_delay": 2,
        "encoder": {"noise_std": 1e-4},
        # plants drawn at every (auto)reset: the packed arguments follow the new plants
        "randomize": {
            "plant_scaling.link_mass": {"low": 0.8, "high": 1.2},
            "unmodelled_friction.coulomb": {"low": 0.0, "high": 0.01},
        },
    },
    "elastic_gym/KR15Elastic-v0": {"task": "regulation"},  # model (2)
    "elastic_gym/IiwaElastic-v0": {"sensor_delay": 1},
    "elastic_gym/TwoLinkRigid-v0": {"encoder": {"noise_std": 1e-4}},
    "elastic_gym/TwoLinkRigidFriction-v0": {"sensor_delay": 1, "task": "excitation"},
}


def _rollout(env_id: str, step_by_step: bool, monkeypatch, steps: int = 200) -> list:
    built = []  # what the packing built: the fused arguments, or None (step by step)
    original = FusedArguments._build

    def build(self):
        built.append(None if step_by_step else original(self))
        return built[-1]

    monkeypatch.setattr(FusedArguments, "_build", build)
    # a low velocity limit: arms break their physics at different times (autoresets)
    envs = gym.make_vec(
        env_id, 3, vectorization_mode="vector_entry_point", max_velocity=1.0, **KWARGS[env_id]
    )
    rng = np.random.default_rng(5)
    out = leaves(envs.reset(seed=11), [])
    high = envs.single_action_space.high
    breaks = 0
    for _ in range(steps):
        action = rng.uniform(-0.8, 0.8, (3, len(high))) * high
        result = envs.step(action)
        breaks += int(result[2].sum())
        out = leaves(result, out)
    envs.close()
    monkeypatch.undo()
    return [out, bool(built) and all(b is not None for b in built), breaks]


@pytest.mark.parametrize("env_id", fast_lane(elastic_gym.ENV_IDS, "elastic_gym/TwoLinkRigid-v0"))
def test_fused_end_of_period_equals_step_by_step(env_id, monkeypatch):
    fused, used, breaks = _rollout(env_id, False, monkeypatch)
    reference, _, _ = _rollout(env_id, True, monkeypatch)
    assert used
    assert breaks > 0  # arms broke their physics: the kernel's early return, autoresets
    assert fused == reference


# the tasks with a compiled form (a task without one, e.g. fourier, is stepped call by call)
COMPILED = sorted(name for name, task in TASKS.items() if "compiled_arguments" in vars(task))


@pytest.mark.parametrize("task", COMPILED)
def test_compiled_period_equals_a_task_stepped_call_by_call(task, monkeypatch):
    """The period kernel against the same task without its compiled form (a task of a
    user's would be stepped so): every leaf of every step equal, an episode length hit."""

    def rollout(compiled: bool) -> tuple[list, bool]:
        if not compiled:
            monkeypatch.setattr(TASKS[task], "compiled_arguments", lambda self: None)
        env = gym.make("elastic_gym/TwoLinkElastic-v0", task=task, episode_time=0.1)
        rng = np.random.default_rng(2)
        out = leaves(env.reset(seed=3), [])
        high = env.action_space.high
        for _ in range(250):
            result = env.step(rng.uniform(-0.3, 0.3, len(high)) * high)
            out = leaves(result, out)
            if result[2] or result[3]:
                out = leaves(env.reset(), out)
        used = env.unwrapped.batch.fused.get().period is not None
        env.close()
        monkeypatch.undo()
        return out, used

    (fast, used), (reference, unused) = rollout(True), rollout(False)
    assert used and not unused
    assert fast == reference
