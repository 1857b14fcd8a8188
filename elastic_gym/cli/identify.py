"""``elastic-gym identify LOG``: fit the elastic-joint model to a sensor log; write the
identified model file, a report and its figure."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

DEFAULT_OUTPUT = "identify_out"


def add_parser(subcommands: argparse._SubParsersAction) -> None:
    parser = subcommands.add_parser(
        "identify",
        help="identify K, D, B, link masses, friction and sensor biases from a sensor log",
        description="Fit the elastic-joint model (De Luca et al. 2007, eq. (1)/(2)) to a "
        "sensor log (motor encoders, motor torques, link accelerometers): per joint K, D, "
        "B, a mass scale of its link, viscous and Coulomb friction, and the accelerometer "
        "biases, with standard errors and a fit on the held-out end of the log. Writes "
        "model.yaml (the identified model: compare/benchmark/train --model), report.md and "
        "identification.png. Parameters the log does not excite are named and held at "
        "their nominal values.",
    )
    parser.add_argument("log", metavar="LOG", help="sensor log (.csv, .parquet, bag, .mcap)")
    parser.add_argument(
        "--output", metavar="DIR", help=f"output folder (default: ./{DEFAULT_OUTPUT}/<log name>)"
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="replace an earlier identification there"
    )
    parser.add_argument(
        "--holdout",
        type=float,
        default=0.2,
        metavar="FRACTION",
        help="end part of the log kept out of the fit to validate it (default 0.2)",
    )
    parser.add_argument(
        "--pass-hz",
        type=float,
        metavar="HZ",
        help="the zero-phase filter's pass band (default: from the sensors' noise)",
    )
    parser.add_argument(
        "--accelerometer-cutoff",
        type=float,
        metavar="HZ",
        help="the accelerometers' first-order low-pass, if they have one (it is undone; "
        "default: the sidecar's accelerometer_cutoff_hz)",
    )
    parser.add_argument(
        "--delay",
        type=float,
        metavar="SECONDS",
        help="the torque acts this much later than logged relative to the sensors (default: "
        "the sidecar's sensor_delay, else 0)",
    )
    parser.add_argument(
        "--no-torque-hold",
        action="store_true",
        help="the torque column holds samples of a continuous torque, not a command held "
        "until the next row (the log format's meaning)",
    )
    parser.add_argument(
        "--coulomb-velocity",
        type=float,
        default=0.01,
        metavar="RAD_S",
        help="Coulomb friction's smoothing velocity v_s in tanh(q'/v_s) (default 0.01)",
    )
    parser.set_defaults(handler=run)


def _settings(args: argparse.Namespace):
    from elastic_gym.identification.fit import FitSettings
    from elastic_gym.identification.signals import Band

    checks = (
        ("--holdout", args.holdout, 0.0 <= args.holdout <= 0.5, "a fraction in [0, 0.5]"),
        ("--pass-hz", args.pass_hz, args.pass_hz is None or args.pass_hz > 0, "> 0"),
        (
            "--accelerometer-cutoff",
            args.accelerometer_cutoff,
            args.accelerometer_cutoff is None or args.accelerometer_cutoff > 0,
            "> 0",
        ),
        ("--delay", args.delay, args.delay is None or 0 <= args.delay < 1.0, "in [0, 1) s"),
        ("--coulomb-velocity", args.coulomb_velocity, args.coulomb_velocity > 0, "> 0"),
    )
    for option, value, ok, what in checks:
        if not ok or (value is not None and value != value):  # NaN
            raise ValueError(f"{option} must be {what}, got {value}")
    band = None if args.pass_hz is None else Band(args.pass_hz, 1.5 * args.pass_hz)
    return FitSettings(band=band, holdout=args.holdout, coulomb_velocity=args.coulomb_velocity)


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from elastic_gym.identification.identify import (
        MODEL_FILE,
        identify,
        sampling_of,
        write_identification,
    )
    from elastic_gym.logs import read_log

    settings = _settings(args)
    log_path = Path(args.log)
    output = Path(args.output) if args.output else Path(DEFAULT_OUTPUT) / log_path.stem
    if (output / MODEL_FILE).exists() and not args.overwrite:
        raise FileExistsError(
            f"{output / MODEL_FILE} exists (an earlier identification); give --overwrite "
            "to replace it or --output for another folder"
        )
    log = read_log(log_path)
    sampling = sampling_of(log, not args.no_torque_hold, args.delay, args.accelerometer_cutoff)
    identification = identify(log, replace(settings, sampling=sampling))
    paths = write_identification(identification, output)
    print(summary(identification))
    for warning in identification.model_file.fit.warnings:
        sys.stderr.write(f"elastic-gym identify: warning: {warning}\n")
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def summary(identification) -> str:
    """A few lines: the identified joint parameters (value ± standard error)."""
    file = identification.model_file
    rows = [f"identified {file.robot} from {file.fit.log} in {identification.result.seconds:.1f} s"]
    fields = (
        ("K", "stiffness"),
        ("D", "damping"),
        ("B", "motor_inertia"),
        ("mass scale", "link_mass_scale"),
        ("F_v", "viscous_friction"),
        ("F_c", "coulomb_friction"),
    )
    for joint in file.joints:
        parts = []
        for label, field in fields:
            e = getattr(joint, field)
            value = f"{e.value:.5g}" + (" (held)" if e.held else f" ± {e.std:.2g}" if e.std else "")
            parts.append(f"{label} {value}")
        rows.append(f"  {joint.name}: " + ", ".join(parts))
    return "\n".join(rows)
