"""Speed of `elastic-gym identify` on a 60 s, 1 kHz TwoLinkElastic log (issue target: 10 s
on 2 cores).

Records the log once (TwoLinkElastic-v0 at its defaults: a motor PD with gravity
compensation on a multi-sine reference plus a 2-25 Hz torque dither, the env's default
sensors), then times, best of ``--repeat``: the command in a fresh process (imports, the
numba cache, reading the CSV, the fit, the report and figure: what a user waits for) and
`identify` alone in this process after a warm-up. Prints the load average with the table:
on a shared machine other processes only ever add time.

    python benchmarks/identify_speed.py [--seconds 60] [--repeat 3] [--log PATH]
        [--markdown docs/results/identification/speed.md]
"""

from __future__ import annotations

import argparse
import datetime
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import elastic_gym
from elastic_gym.identification.identify import identify
from elastic_gym.logs import SensorLog, read_log, write_log


def record(path: Path, seconds: float, seed: int = 0) -> Path:
    """A TwoLinkElastic log of ``seconds`` (see the module docstring)."""
    env = gym.make("elastic_gym/TwoLinkElastic-v0", task="regulation", episode_time=None)
    batch = env.unwrapped
    model, n, dt = batch.model, batch.n_joints, batch.control_dt
    rng = np.random.default_rng(seed)
    centre = 0.5 * (np.asarray(model.spec.workspace_low) + np.asarray(model.spec.workspace_high))
    w = 2 * np.pi * 0.1 * np.arange(1, 6)
    amplitude = rng.uniform(0.05, 0.2, (5, n))
    f = np.exp(rng.uniform(np.log(2.0), np.log(25.0), (40, n)))
    phase = rng.uniform(0, 2 * np.pi, (40, n))
    limit = batch.torque_limit
    obs, info = env.reset(seed=seed, options={"initial_state": {"q": centre.tolist()}})
    J = model.B + np.diag(model.mass_matrix(centre))
    kp, kd = 400.0 * J, 28.0 * J
    steps = round(seconds / dt)
    rows = {k: np.zeros((steps + 1, m)) for k, m in (("theta", n), ("tau", n), ("acc", 6))}
    for k in range(steps + 1):
        t = k * dt
        qd = centre + np.sin(w * t) @ amplitude
        g = model.gravity(qd)
        tau = (
            g + kp * (qd + g / model.K - obs["motor_position"]) - kd * info["true_state"]["dtheta"]
        )
        tau = tau + 0.03 * limit * np.sqrt(2 / 40) * np.sin(2 * np.pi * f * t + phase).sum(0)
        rows["theta"][k], rows["acc"][k] = obs["motor_position"], obs["acceleration"]
        obs, _, _, _, info = env.step(np.clip(tau, -limit, limit))
        rows["tau"][k] = info["torque"]
    env.close()
    sidecar = {"robot": "TwoLinkElastic-v0", "sample_time": dt}
    times = np.arange(steps + 1) * dt
    log = SensorLog.create(sidecar, times, rows["theta"], rows["tau"], rows["acc"])
    return write_log(path, log)[0]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--log", type=Path, help="the log (recorded there first if missing)")
    parser.add_argument("--markdown", type=Path, help="also write the table to this file")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as scratch:
        path = args.log or Path(scratch) / "two_link.csv"
        if not path.exists():
            record(path, args.seconds)
        command = [sys.executable, "-m", "elastic_gym.cli", "identify", str(path), "--overwrite"]
        command += ["--output", str(Path(scratch) / "out")]
        wall, cpu = [], []
        for _ in range(args.repeat):
            start, children = time.perf_counter(), os.times()
            subprocess.run(command, check=True, capture_output=True)
            wall.append(time.perf_counter() - start)
            after = os.times()
            cpu.append(
                after.children_user
                + after.children_system
                - children.children_user
                - children.children_system
            )
        log = read_log(path)
        identify(log)  # warm-up: numba's cache, first calls
        fit, fit_cpu = [], []
        for _ in range(args.repeat):
            start, process = time.perf_counter(), time.process_time()
            result = identify(log).result
            fit.append(time.perf_counter() - start)
            fit_cpu.append(time.process_time() - process)
    load = os.getloadavg()
    lines = [
        f"elastic-gym {elastic_gym.__version__}, {datetime.date.today().isoformat()}; "
        f"{os.cpu_count()} CPUs; load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; "
        f"log: {len(log)} samples, {log.duration:.0f} s at {1 / log.sample_time:.0f} Hz; fit: "
        f"{result.evaluations} residual evaluations, pass band {result.band.pass_hz:.1f} Hz.",
        "",
        "| what | wall, best (s) | CPU, best (s) | wall, every run (s) | target (s) |",
        "|---|---:|---:|---|---:|",
        f"| `elastic-gym identify` (fresh process) | {min(wall):.2f} | {min(cpu):.2f} | "
        + " ".join(f"{t:.2f}" for t in wall)
        + " | 10 |",
        f"| `identify()` in a warm process | {min(fit):.2f} | {min(fit_cpu):.2f} | "
        + " ".join(f"{t:.2f}" for t in fit)
        + " | |",
    ]
    print("\n".join(lines))
    if args.markdown:
        args.markdown.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
