"""Shared fixtures: every registered env id, and a quiet, noise-free env factory; before
xdist starts its workers, numba's cache is filled by two processes (``warmup.py``)."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# Small matrices: OpenBLAS threads competing for 2 cores make expm/solve 100x slower.
# Set before numpy is imported (pytest-xdist workers inherit it).
for _key in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_key, "1")

import gymnasium as gym  # noqa: E402
import pytest  # noqa: E402

import elastic_gym  # noqa: E402

WARMUP_BOUND = 1200.0  # s for the two warm-up processes (a cold cache on a loaded machine)
_warmup_report: list[str] = []


def pytest_configure(config):
    """On the xdist controller (``-n`` given; not in a worker): compile the kernels into
    numba's cache in two processes at once, before the workers start and load them.
    ``ELASTIC_GYM_NO_WARMUP=1`` skips it. A failed warm-up fails nothing: the tests then
    compile what they call, and fail themselves if something is wrong."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    if os.environ.get("ELASTIC_GYM_NO_WARMUP"):
        return
    started = time.monotonic()
    package_root = str(Path(elastic_gym.__file__).resolve().parents[1])  # what workers import
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([package_root, os.environ.get("PYTHONPATH", "")]),
    }
    script = str(Path(__file__).with_name("warmup.py"))
    with tempfile.TemporaryDirectory() as markers:
        logs = {part: Path(markers) / f"{part}.log" for part in ("a", "b")}
        children = {}
        for part, log in logs.items():
            with log.open("w") as handle:
                children[part] = subprocess.Popen(
                    [sys.executable, script, part, markers],
                    env=env,
                    stdout=handle,
                    stderr=subprocess.STDOUT,
                    stdin=subprocess.DEVNULL,
                )
        for part, child in children.items():
            try:
                code = child.wait(timeout=max(1.0, started + WARMUP_BOUND - time.monotonic()))
            except subprocess.TimeoutExpired:
                child.kill()
                code = child.wait()
            steps = ", ".join(logs[part].read_text().splitlines()[-12:])
            _warmup_report.append(f"part {part} (exit {code}): {steps}")
    _warmup_report.insert(0, f"numba warm-up: {time.monotonic() - started:.1f} s")


def pytest_report_header(config):
    return _warmup_report


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
