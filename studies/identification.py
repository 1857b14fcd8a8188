"""Accuracy of `elastic-gym identify` on simulated logs of plants the model does not know.

For each elastic robot: ``--plants`` plants drawn from a fixed seed, each joint's K, B, D
and link mass x U[0.7, 1.3] around nominal, plus link friction the nominal model lacks
(Coulomb U[0.5, 2] %, viscous U[0.2, 1] % s/rad of the joint's torque limit); one
``--seconds`` log each, recorded by the envs (all plants of a robot in one vector env, the
default sensor noise and biases, physics step ``--physics-dt``) under a motor PD with
gravity compensation that tracks a multi-sine reference (5 harmonics of 0.1 Hz) plus a
multi-sine torque dither across 2-25 Hz (3 % of the torque limits, RMS); each log written
as CSV + sidecar (the plant in its provenance) and identified from its columns alone
(`read_log` + `identify`, as the command does). The errors against the plants go to
``docs/results/identification/`` (CSV, markdown, figure); ``--report`` only rebuilds
them from the identified model files. ``python studies/identification.py --help``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import elastic_gym
from elastic_gym.envs.plant import PlantArray
from elastic_gym.envs.sensors import AccelerometerArray, AccelerometerConfig, Encoder, every_arm
from elastic_gym.identification.identify import identify, write_identification
from elastic_gym.logs import SensorLog, read_log, write_log
from elastic_gym.model import RobotModel
from elastic_gym.model.identified import load_identified_model
from elastic_gym.model.integrator import ArmIntegrator
from elastic_gym.robots.catalog import get_robot
from elastic_gym.robots.spec import LinkFriction

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "docs" / "results" / "identification"
ROBOTS = {
    "two-link": "elastic_gym/TwoLinkElastic-v0",
    "kr15": "elastic_gym/KR15Elastic-v0",
    "iiwa": "elastic_gym/IiwaElastic-v0",
}
TARGETS = {  # the targets: relative for the plant parameters, m/s^2 for the biases
    "stiffness": 0.01,
    "motor_inertia": 0.02,
    "link_mass": 0.02,
    "damping": 0.15,
    "friction": 0.25,
    "bias": 0.005,
}
PARAMETERS = ("stiffness", "damping", "motor_inertia", "link_mass", "viscous", "coulomb")
DITHER_HZ = (2.0, 25.0)
DITHER_FRACTION = 0.03


def draw_plants(n_joints: int, count: int, seed: int) -> list[dict]:
    """``count`` plants: per-joint scalings x U[0.7, 1.3] and unmodelled friction."""
    rng = np.random.default_rng(seed)
    plants = []
    for _ in range(count):
        scaling = {
            key: [float(v) for v in rng.uniform(0.7, 1.3, n_joints)]
            for key in ("stiffness", "motor_inertia", "damping", "link_mass")
        }
        friction = {
            "coulomb": [float(v) for v in rng.uniform(0.005, 0.02, n_joints)],
            "viscous": [float(v) for v in rng.uniform(0.002, 0.01, n_joints)],
        }
        plants.append({"plant_scaling": scaling, "unmodelled_friction": friction})
    return plants


def fourier_reference(rng, low, high, base_hz=0.1, harmonics=5):
    """q_d, q_d', q_d'' at time t: a random Fourier series in 60 % of [low, high]."""
    n = len(low)
    centre, half = (low + high) / 2, 0.3 * (high - low)
    k = np.arange(1, harmonics + 1)
    a, b = (rng.normal(size=(harmonics, n)) / k[:, None] for _ in range(2))
    w = 2 * np.pi * base_hz * k
    t = np.linspace(0, 1 / base_hz, 4000)
    peak = np.max(np.abs(np.sin(np.outer(t, w)) @ a + np.cos(np.outer(t, w)) @ b), axis=0)
    a, b = a * half / peak, b * half / peak

    def reference(t):  # t scalar, or (T, 1) for every sample at once
        s, c = np.sin(w * t), np.cos(w * t)
        return centre + s @ a + c @ b, (c * w) @ a - (s * w) @ b, -(s * w**2) @ a - (c * w**2) @ b

    return reference


def dither(rng, n_arms, n, limit, count=40):
    """tau_d(t) (n_arms, n): sums of sines at log-uniform frequencies across DITHER_HZ."""
    f = np.exp(rng.uniform(*np.log(DITHER_HZ), size=(n_arms, count, n)))
    phase = rng.uniform(0, 2 * np.pi, size=(n_arms, count, n))
    scale = DITHER_FRACTION * np.asarray(limit) * np.sqrt(2.0 / count)
    return lambda t: scale * np.sum(np.sin(2 * np.pi * f * t + phase), axis=1)


def record(robot: str, plants: list[dict], seconds: float, seed: int, out: Path) -> None:
    """One log per plant, written as ``out/plant<k>.csv`` (and the biases the sensors drew,
    ``out/biases.json``): all plants at once through the package's compiled RK4 of model
    (1)/(2) with step-size control (`elastic_gym.model.integrator`, tolerances 1e-9 rad,
    1e-6 rad/s per substep; the torque held over each 1 ms period) and the envs' sensor
    models at their defaults (`Encoder`, `AccelerometerArray`: quantized encoders, noise,
    biases drawn per arm)."""
    env_id = ROBOTS[robot]
    spec = get_robot(gym.spec(env_id).kwargs["robot"])
    nominal = RobotModel(spec)
    n, N, dt = spec.n_joints, len(plants), spec.control_dt
    limit = np.asarray(spec.torque_limit)
    models = [
        RobotModel(
            spec,
            plant["plant_scaling"],
            added_friction=LinkFriction(
                viscous=tuple(limit * plant["unmodelled_friction"]["viscous"]),
                coulomb_pos=tuple(limit * plant["unmodelled_friction"]["coulomb"]),
            ),
        )
        for plant in plants
    ]
    array = PlantArray(models)
    coupling = (array.SBinv, array.schur_inertia, array.ST) if array.has_coupling else None
    integrator = ArmIntegrator(array.chain, array.transmission, coupling, elastic=True)
    rng = np.random.default_rng(seed)
    low, high = np.asarray(spec.workspace_low), np.asarray(spec.workspace_high)
    reference = fourier_reference(rng, low, high)
    tau_dither = dither(rng, N, n, limit)
    rngs = [np.random.default_rng([seed, arm]) for arm in range(N)]
    arms = every_arm(N)
    encoder = Encoder(spec.encoder_resolution, spec.encoder_noise_std, n, N)
    accelerometers = AccelerometerArray(AccelerometerConfig(), nominal.n_sensors, dt, N)
    accelerometers.reset(arms, rngs)
    q0 = reference(0.0)[0]
    q = np.ascontiguousarray(np.tile(q0, (N, 1)))
    theta = np.ascontiguousarray(q + array.chain.gravity(q) / array.K)  # at rest
    dq, dtheta = np.zeros((N, n)), np.zeros((N, n))
    ddq = np.ascontiguousarray(
        integrator.derivative(theta, dtheta, q, dq, np.zeros((N, n)))[:, 3 * n :]
    )
    J = nominal.B + np.diag(nominal.mass_matrix(q0))
    omega = 20.0
    kp, kd = J * omega**2, 2 * 0.7 * J * omega
    steps = round(seconds / dt)
    time_ = np.arange(steps + 1) * dt
    # the reference's feedforward g + M q_d'' + B q_d'' and motor positions, all at once
    qd, dqd, ddqd = (np.ascontiguousarray(x) for x in reference(time_[:, None]))
    chain = nominal.chain
    g = chain.gravity(qd)
    feedforward = chain.rnea(qd, np.zeros_like(qd), ddqd) + nominal.B * ddqd
    theta_d = qd + g / nominal.K
    log_theta, torque = np.zeros((steps + 1, N, n)), np.zeros((steps + 1, N, n))
    acc = np.zeros((steps + 1, N, 3 * nominal.n_sensors))
    for k in range(steps + 1):
        measured = encoder.measure(theta, rngs, arms)
        forces = array.chain.specific_forces(q, dq, ddq)
        acc[k] = accelerometers.measure(forces, rngs, arms)
        tau = feedforward[k] + kp * (theta_d[k] - measured) + kd * (dqd[k] - dtheta)
        tau = np.ascontiguousarray(np.clip(tau + tau_dither(time_[k]), -limit, limit))
        log_theta[k], torque[k] = measured, tau
        integrator.step(theta, dtheta, q, dq, tau, dt, ddq=ddq)
        if not np.all(np.isfinite(q)):
            raise RuntimeError(f"{robot}: the simulation diverged at {time_[k]:.3f} s")
    out.mkdir(parents=True, exist_ok=True)
    (out / "biases.json").write_text(json.dumps(accelerometers.bias.tolist()))
    for arm, plant in enumerate(plants):
        sidecar = {
            "robot": env_id.split("/")[1],
            "sample_time": dt,
            "provenance": {
                "writer": "studies/identification.py",
                "version": elastic_gym.__version__,
                "env_id": env_id,
                "env_kwargs": plant,
                "seed": seed,
                "excitation": {
                    "reference": "Fourier, 5 harmonics of 0.1 Hz",
                    "dither_hz": list(DITHER_HZ),
                    "dither_fraction": DITHER_FRACTION,
                },
                "notes": "elastic_gym.model.integrator RK4, envs' default sensor models",
            },
        }
        log = SensorLog.create(sidecar, time_, log_theta[:, arm], torque[:, arm], acc[:, arm])
        write_log(out / f"plant{arm}.csv", log)


def truth(log: SensorLog) -> dict[str, np.ndarray]:
    """The plant's parameters from the log's provenance (a study reads it; identify never)."""
    kwargs = log.sidecar.provenance.env_kwargs or {}
    spec = log.robot
    scaling = kwargs["plant_scaling"]
    friction = kwargs["unmodelled_friction"]
    limit = np.asarray(spec.torque_limit)
    return {
        "stiffness": np.asarray(spec.stiffness) * scaling["stiffness"],
        "damping": np.asarray(spec.damping) * scaling["damping"],
        "motor_inertia": np.asarray(spec.motor_inertia) * scaling["motor_inertia"],
        "link_mass": np.asarray(scaling["link_mass"]),
        "viscous": limit * np.asarray(friction["viscous"]),
        "coulomb": limit * np.asarray(friction["coulomb"]),
    }


def errors(log: SensorLog, model_path: Path, bias: np.ndarray | None) -> dict[str, np.ndarray]:
    """Relative errors per joint of each parameter (biases: absolute, m/s^2)."""
    file = load_identified_model(model_path)
    true = truth(log)
    fields = {
        "stiffness": "stiffness",
        "damping": "damping",
        "motor_inertia": "motor_inertia",
        "link_mass": "link_mass_scale",
        "viscous": "viscous_friction",
        "coulomb": "coulomb_friction",
    }
    out = {key: file.values(field) / true[key] - 1.0 for key, field in fields.items()}
    out["held"] = np.array(
        [getattr(j, f).held for j in file.joints for f in fields.values()], dtype=bool
    )
    if bias is not None:
        identified = np.concatenate([a.bias for a in file.accelerometers])
        out["bias"] = identified - bias
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", choices=list(ROBOTS), default=list(ROBOTS))
    parser.add_argument("--plants", type=int, default=10)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--out", type=Path, default=Path("identification_out"))
    parser.add_argument("--report", action="store_true", help="only rebuild the tables")
    args = parser.parse_args(argv)
    rows = []
    for index, robot in enumerate(args.robots):
        folder = args.out / robot
        n = get_robot(gym.spec(ROBOTS[robot]).kwargs["robot"]).n_joints
        plants = draw_plants(n, args.plants, args.seed + 100 * index)
        if not args.report and not all(
            (folder / f"plant{k}.csv").exists() for k in range(len(plants))
        ):
            start = time.perf_counter()
            record(robot, plants, args.seconds, args.seed + index, folder)
            print(
                f"{robot}: recorded {len(plants)} logs in {time.perf_counter() - start:.0f} s",
                flush=True,
            )
        biases = json.loads((folder / "biases.json").read_text())
        for k in range(len(plants)):
            path = folder / f"plant{k}.csv"
            result_dir = folder / f"plant{k}"
            log = read_log(path)
            if not args.report and not (result_dir / "model.yaml").exists():
                identification = identify(log)
                write_identification(identification, result_dir)
                seconds = identification.result.seconds
                print(f"{robot} plant{k}: identified in {seconds:.1f} s", flush=True)
            rows.append((robot, k, errors(log, result_dir / "model.yaml", np.array(biases[k]))))
    write_tables(rows, args)
    return 0


def write_tables(rows, args) -> None:
    """docs/results/identification/: errors.csv (every plant and joint), summary.md."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    lines = ["robot,plant,parameter,joint,error,held"]
    summary = {}
    for robot, k, err in rows:
        held = err["held"].reshape(-1, 6)
        for p, key in enumerate(
            ("stiffness", "damping", "motor_inertia", "link_mass", "viscous", "coulomb")
        ):
            for j, value in enumerate(err[key]):
                lines.append(f"{robot},{k},{key},{j + 1},{value:.6g},{int(held[j, p])}")
                summary.setdefault((robot, key), []).append((abs(value), bool(held[j, p])))
        for c, value in enumerate(err.get("bias", [])):
            lines.append(f"{robot},{k},bias,{c + 1},{value:.6g},0")
            summary.setdefault((robot, "bias"), []).append((abs(value), False))
    (RESULTS / "errors.csv").write_text("\n".join(lines) + "\n")
    table = [
        f"elastic-gym {elastic_gym.__version__}, {datetime.date.today().isoformat()}: "
        f"{args.plants} plants per robot, {args.seconds:g} s logs.",
        "",
        "| robot | parameter | target | median | 90 % | max | within target | held |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for (robot, key), values in summary.items():
        errs = np.array([v for v, _ in values])
        held = sum(h for _, h in values)
        target = TARGETS["friction" if key in ("viscous", "coulomb") else key]
        unit = " m/s²" if key == "bias" else " %"
        scale = 1.0 if key == "bias" else 100.0
        within = int(np.sum(errs <= target))
        table.append(
            f"| {robot} | {key} | {scale * target:g}{unit} | {scale * np.median(errs):.3g} | "
            f"{scale * np.quantile(errs, 0.9):.3g} | {scale * errs.max():.3g} | "
            f"{within}/{len(errs)} | {held} |"
        )
    (RESULTS / "summary.md").write_text("\n".join(table) + "\n")
    error_figure(summary)
    print("\n".join(table))


def error_figure(summary: dict) -> None:
    """errors.png: every joint's (every axis') error per parameter and robot, against the
    target (dashed), on a log scale; held parameters as crosses."""
    from matplotlib.figure import Figure

    keys = (*PARAMETERS, "bias")
    robots = list(dict.fromkeys(robot for robot, _ in summary))
    figure = Figure(figsize=(11, 3.4), constrained_layout=True)
    axes = figure.subplots(1, len(keys))
    rng = np.random.default_rng(0)
    for ax, key in zip(axes, keys, strict=True):
        target = TARGETS["friction" if key in ("viscous", "coulomb") else key]
        scale = 1.0 if key == "bias" else 100.0
        for r, robot in enumerate(robots):
            values = summary.get((robot, key), [])
            errs = np.array([v for v, _ in values]) * scale
            held = np.array([h for _, h in values], dtype=bool)
            x = r + rng.uniform(-0.2, 0.2, len(errs))
            ax.scatter(x[~held], np.maximum(errs[~held], 1e-6), s=6, alpha=0.6)
            ax.scatter(x[held], np.maximum(errs[held], 1e-6), s=14, marker="x", color="k")
        ax.axhline(scale * target, ls="--", color="tab:red", lw=1)
        ax.set_yscale("log")
        ax.set_xticks(range(len(robots)), robots, rotation=45, fontsize=7)
        unit = "m/s²" if key == "bias" else "%"
        ax.set_title(f"{key} ({unit})", fontsize=8)
    figure.suptitle(
        "|identified - plant| per joint (biases per axis); dashed: the target", fontsize=9
    )
    figure.savefig(RESULTS / "errors.png", dpi=90)


if __name__ == "__main__":
    sys.exit(main())
