"""Shared fixtures: every registered env id, and a quiet, noise-free env factory; before
xdist starts its workers, numba's cache is filled by two processes
(`elastic_gym.precompile`)."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

# Small matrices: OpenBLAS threads competing for 2 cores make expm/solve 100x slower.
# Set before numpy is imported (pytest-xdist workers inherit it).
for _key in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_key, "1")

import pytest  # noqa: E402
from helpers import ELASTIC_IDS, jobs_here  # noqa: E402

import elastic_gym  # noqa: E402
from elastic_gym.precompile import precompile  # noqa: E402

WARMUP_BOUND = 1200.0  # s for the two warm-up processes (a cold cache on a loaded machine)
_warmup_report: list[str] = []


def pytest_configure(config):
    """On the xdist controller (``-n`` given; not in a worker): compile the kernels into
    numba's cache in two processes at once (`elastic_gym.precompile`), before the workers
    start and load them. ``ELASTIC_GYM_NO_WARMUP=1`` skips it. A failed warm-up fails
    nothing: the tests then compile what they call, and fail themselves if something is
    wrong. Skipped when the last warm-up that succeeded saw the same sources (a stamp in
    ``.pytest_cache``: delete it with the numba cache files to measure a cold run)."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    if os.environ.get("ELASTIC_GYM_NO_WARMUP"):
        return
    package = Path(elastic_gym.__file__).resolve().parent  # what the workers import
    sources = sorted(package.rglob("*.py"))
    stamp = [sys.version, *(f"{f} {f.stat().st_mtime_ns} {f.stat().st_size}" for f in sources)]
    cache = getattr(config, "cache", None)  # pytest's cache folder (none with -p no:cacheprovider)
    if cache is not None and cache.get("elastic_gym/numba-warmup", None) == stamp:
        return  # warmed up for these very sources (numba's cache keys on their mtime and size)
    started = time.monotonic()
    try:
        precompile(jobs=2, bound=WARMUP_BOUND, progress=_warmup_report.append)
    except RuntimeError as exc:
        _warmup_report.append(str(exc))
    else:
        if cache is not None:
            cache.set("elastic_gym/numba-warmup", stamp)
    _warmup_report.insert(0, f"numba warm-up: {time.monotonic() - started:.1f} s")


def pytest_report_header(config):
    return _warmup_report


def pytest_terminal_summary(terminalreporter):
    for line in _warmup_report:  # also under -q, which hides the header
        terminalreporter.write_line(line)


RIGID_IDS = [i for i in elastic_gym.ENV_IDS if "Rigid" in i]


@pytest.fixture
def single_thread_torch():
    """One torch thread during a test (training tests on 2 cores: threads compete)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def jobs_in_this_process(monkeypatch):
    """``workers=1`` runs its jobs in this process, as it does for jobs that refer to
    ``__main__`` (`elastic_gym.runtime.parallel.for_each_result`, the comparison's and the
    benchmark's execution): for a test whose claim is the results, not the worker process
    (a spawned worker imports the package and torch again: seconds of CPU each)."""
    jobs_here(monkeypatch)


@pytest.fixture(params=elastic_gym.ENV_IDS)
def env_id(request) -> str:
    return request.param


@pytest.fixture(params=ELASTIC_IDS)
def elastic_id(request) -> str:
    return request.param
