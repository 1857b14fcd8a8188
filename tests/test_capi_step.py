"""The substeps through PyBullet's C API equal the substeps through its Python functions.

Where `bullet_capi.client_slot` finds a connection's C handle, `ArmSimulator` steps its
world from compiled code (a control period in one call). Batches of every id, with
per-arm plants, payloads, torque pulses, sensor noise and arms breaking their physics,
must give bit for bit the observations, rewards, terminations and info of the same batch
stepped through PyBullet's Python functions.
"""

from __future__ import annotations

import sys

import gymnasium as gym
import numpy as np
import pybullet as p
import pytest
from helpers import fast_lane, leaves

import elastic_gym
from elastic_gym.envs import bullet_capi

PULSES = {"times": [0.01, 0.03], "durations": [0.005, 0.02], "amplitudes": [3.0, -2.0]}
KWARGS = {
    "elastic_gym/TwoLinkElastic-v0": {
        "torque_pulses": PULSES,
        "encoder": {"noise_std": 1e-4},
        "per_arm": [{"payload": {"mass": 0.5}}, {"plant_scaling": {"link_mass": 1.3}}, {}],
    },
    "elastic_gym/KR15Elastic-v0": {"task": "regulation", "torque_pulses": PULSES},
    "elastic_gym/IiwaElastic-v0": {"per_arm": [{}, {"plant_scaling": {"stiffness": 0.9}}, {}]},
    "elastic_gym/TwoLinkRigid-v0": {"torque_pulses": PULSES},
    "elastic_gym/TwoLinkRigidFriction-v0": {"task": "excitation", "sensor_delay": 1},
}


def _rollout(env_id: str, python: bool, monkeypatch, steps: int = 120) -> tuple[list, bool]:
    if python:
        monkeypatch.setattr(bullet_capi, "client_slot", lambda client: None)
    envs = gym.make_vec(
        env_id, 3, vectorization_mode="vector_entry_point", max_velocity=1.0, **KWARGS[env_id]
    )
    compiled = envs.unwrapped.batch.sim._slot is not None
    rng = np.random.default_rng(3)
    out = leaves(envs.reset(seed=4), [])
    high = envs.single_action_space.high
    for _ in range(steps):
        out = leaves(envs.step(rng.uniform(-0.8, 0.8, (3, len(high))) * high), out)
    envs.close()
    monkeypatch.undo()
    return out, compiled


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="ELF builds of PyBullet")
def test_the_c_handle_is_found_on_linux():
    client = p.connect(p.DIRECT)
    try:
        slot = bullet_capi.client_slot(client)
        assert slot is not None and slot[0] != 0
    finally:
        p.disconnect(client)
    assert slot[0] == 0  # the live entry: PyBullet cleared it
    assert bullet_capi.client_slot(client) is None


@pytest.mark.parametrize("env_id", fast_lane(elastic_gym.ENV_IDS, "elastic_gym/TwoLinkElastic-v0"))
def test_c_api_substeps_equal_the_python_functions(env_id, monkeypatch):
    compiled, used = _rollout(env_id, False, monkeypatch)
    python, fallback = _rollout(env_id, True, monkeypatch)
    assert used == sys.platform.startswith("linux") and not fallback
    assert compiled == python


def test_a_world_disconnected_behind_the_env_raises_pybullet_error():
    env = gym.make("elastic_gym/TwoLinkElastic-v0")
    env.reset(seed=0)
    sim = env.unwrapped.batch.sim
    p.disconnect(physicsClientId=sim.client)
    try:
        with pytest.raises(p.error, match="Not connected"):
            env.step(np.zeros(2))
    finally:  # now, before another test's world takes the client id the env still holds
        env.close()


def test_the_symbol_lookup_reads_elf_files_only():
    assert bullet_capi._elf_symbols(__file__, ("sPhysicsClients1",)) == {}  # not ELF
    if sys.platform.startswith("linux"):
        found = bullet_capi._elf_symbols(p.__file__, ("sPhysicsClients1", "no_such_symbol"))
        assert set(found) == {"sPhysicsClients1"}
        assert found["sPhysicsClients1"][1] == 8 * 1024  # MAX_PHYSICS_CLIENTS pointers


def test_a_build_missing_a_c_function_steps_through_python(monkeypatch):
    monkeypatch.setattr(bullet_capi, "_MISSING", ["b3GetJointState"])
    bullet_capi._table_address.cache_clear()
    try:
        client = p.connect(p.DIRECT)
        assert bullet_capi.client_slot(client) is None
        p.disconnect(client)
    finally:
        monkeypatch.undo()
        bullet_capi._table_address.cache_clear()
