"""Job functions and a controller for the worker pool's tests, in a module of their own:
workers import the module of what they run, and this one is light (a test module
imports far more)."""

from __future__ import annotations

import os
import time

import numpy as np
from numba.core.registry import cpu_target
from threadpoolctl import threadpool_info

from elastic_gym.controllers.base import Controller


def pid_of(job: int) -> tuple[int, int]:
    return job, os.getpid()


def os_exit_on_two(job: int) -> int:
    if job == 2:
        os._exit(5)
    return job


def slow_square(job: int) -> int:
    time.sleep(0.05 * job)
    return job * job


def what_a_job_sees(job: int) -> dict:
    print(f"job {job} in {os.getpid()}", flush=True)
    return {
        "pid": os.getpid(),
        "parent": os.getppid(),
        "mark": os.environ.get("ELASTIC_GYM_TEST_MARK"),
        "blas": os.environ.get("OPENBLAS_NUM_THREADS"),
        "blas threads": {pool["num_threads"] for pool in threadpool_info()},
        "cwd": os.getcwd(),
        "draw": np.random.random(),  # noqa: NPY002 - the global generator, never seeded
        "numba ready": numba_registries() > 0,
    }


def numba_registries() -> int:
    """How many registries numba's CPU target has installed in this process (none before
    its first compile, cache load or refresh)."""
    return len(cpu_target.target_context._registries)


class PidLog(Controller):
    """Zero torque; appends the pid of the process that builds it to ``log``."""

    name = "pid-log"

    def __init__(self, model, dt, log: str = ""):
        super().__init__(model, dt)
        with open(log, "a") as handle:
            handle.write(f"{os.getpid()}\n")

    def __call__(self, obs, info):
        return np.zeros(self.n)
