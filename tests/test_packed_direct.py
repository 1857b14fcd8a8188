"""`model.packed.direct`: a kernel's compiled entry point gives the dispatcher's numbers,
and without numba's private fingerprint helper the env steps through the dispatcher with
the same numbers."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from numba import njit

from elastic_gym.model import packed


@njit(cache=False)
def _axpy(a, x, out):
    for i in range(x.shape[0]):
        out[i] = a * x[i] + out[i]


def test_the_entry_point_gives_the_dispatchers_numbers():
    x = np.linspace(-1.0, 1.0, 7)
    through_dispatch, through_entry = np.full(7, 0.3), np.full(7, 0.3)
    _axpy(1.7, x, through_dispatch)
    entry = packed.direct(_axpy, 1.7, x, through_entry)
    assert entry is not _axpy
    entry(1.7, x, through_entry)
    np.testing.assert_array_equal(through_entry, through_dispatch)


def _steps(env_id: str) -> list[np.ndarray]:
    env = gym.make(env_id, integrator="rk4")
    obs, _ = env.reset(seed=3)
    rows = [obs["acceleration"]]
    for k in range(5):
        obs, *_ = env.step(np.full(2, 0.1 * k))
        rows.append(obs["acceleration"])
    env.close()
    return rows


def test_without_the_fingerprint_helper_the_env_steps_the_same(monkeypatch):
    env_id = "elastic_gym/TwoLinkElastic-v0"
    expected = _steps(env_id)
    monkeypatch.setattr(packed, "compute_fingerprint", None)
    assert packed.direct(_axpy, 1.0, np.zeros(1), np.zeros(1)) is _axpy
    for got, want in zip(_steps(env_id), expected, strict=True):
        np.testing.assert_array_equal(got, want)
