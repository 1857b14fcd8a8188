"""Shared fixtures: every registered env id, and a quiet, noise-free env factory."""

from __future__ import annotations

import os

# Small matrices: OpenBLAS threads competing for 2 cores make expm/solve 100x slower.
# Set before numpy is imported (pytest-xdist workers inherit it).
for _key in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_key, "1")

import gymnasium as gym  # noqa: E402
import pytest  # noqa: E402

import elastic_gym  # noqa: E402

ELASTIC_IDS = [i for i in elastic_gym.ENV_IDS if "Elastic" in i]
RIGID_IDS = [i for i in elastic_gym.ENV_IDS if "Rigid" in i]
NOISE_FREE = {"encoder": {"resolution": 0.0, "noise_std": 0.0}, "accelerometer": "ideal"}


def make_noise_free(env_id: str, **kwargs) -> gym.Env:
    """An env whose sensors are exact (ideal encoders and accelerometers)."""
    return gym.make(env_id, **{**NOISE_FREE, **kwargs})


@pytest.fixture
def single_thread_torch():
    """One torch thread during a test (training tests on 2 cores: threads compete)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(params=elastic_gym.ENV_IDS)
def env_id(request) -> str:
    return request.param


@pytest.fixture(params=ELASTIC_IDS)
def elastic_id(request) -> str:
    return request.param
