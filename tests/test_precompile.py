"""`elastic_gym.precompile`: the steps it plans, the kernels it counts, and a cache that a
later process loads instead of compiling."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import numba
import numpy as np
import pytest

from elastic_gym import precompile as pc
from elastic_gym.cli import main


def test_one_process_runs_every_step_once_after_what_it_waits_for():
    order = pc.one_process_order()
    assert sorted(order) == sorted(pc.STEPS)
    for part, steps in pc.PARTS.items():
        mine = [step for step in steps if step in pc.STEPS]
        assert [step for step in order if step in mine] == mine  # each part's own order
        for i, step in enumerate(steps):
            if step.startswith("wait:"):
                marker = f"mark:{step[5:]}"
                (other,) = [p for p, s in pc.PARTS.items() if marker in s]
                assert other != part
                before = pc.PARTS[other][: pc.PARTS[other].index(marker)]
                after = [s for s in steps[i:] if s in pc.STEPS]
                for compiled_first in (s for s in before if s in pc.STEPS):
                    assert all(order.index(compiled_first) < order.index(s) for s in after), (
                        compiled_first,
                        after,
                    )


def test_parts_that_wait_for_each_other_are_refused():
    with pytest.raises(ValueError, match="wait for markers no part writes"):
        pc.one_process_order({"a": ["wait:x", "mark:y"], "b": ["wait:y", "mark:x"]})


def test_a_step_counts_the_kernels_it_compiled(monkeypatch):
    @numba.njit
    def tiny(x):
        return 2.0 * x

    monkeypatch.setitem(pc.STEPS, "tiny", lambda: tiny(np.float64(1.0)))
    assert pc._timed("tiny")[1] == 1
    assert pc._timed("tiny")[1] == 0  # compiled in this process already


def test_bad_jobs_are_refused():
    with pytest.raises(ValueError, match="jobs must be 1 or 2"):
        pc.precompile(jobs=3)
    with pytest.raises(SystemExit) as exit_:
        main(["precompile", "--jobs", "3"])
    assert exit_.value.code == 2


@pytest.mark.slow
def test_two_processes_fill_a_cache_that_a_later_process_loads(capsys):
    """``elastic-gym precompile``: both parts run every step of theirs; then a fresh
    process running every step compiles nothing (on a cold cache the two processes
    compile; on the suite's warm one they load, as the later process must)."""
    assert main(["precompile"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "compiling the kernels into numba's cache (2 processes) ..."
    reported = [step.split()[0] for line in lines[1:3] for step in line[8:].split(", ")]
    assert [line[:8] for line in lines[1:3]] == ["part a: ", "part b: "]
    assert sorted(reported) == sorted(pc.STEPS)
    assert re.fullmatch(r"\d+ kernels compiled in [\d.]+ s \(9 steps, 2 processes\)", lines[3])
    code = (
        "import json; from elastic_gym.precompile import precompile; "
        "print(json.dumps(precompile(jobs=1)))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    later = json.loads(done.stdout.splitlines()[-1])
    assert {step: compiled for step, _, compiled in later} == dict.fromkeys(pc.STEPS, 0)
