"""`elastic-gym record ENV`: a sensor log from an env, the identification excitation
(a Fourier-series reference designed for a well-conditioned regressor, plus a torque
dither across the torsion modes) or a scenario's controller and task; the excitation can
also be written as a reference file for a real robot to follow."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from elastic_gym.logs.record import (
    DEFAULT_CONTROLLER,
    DEFAULT_SOURCE,
    RIGID_CONTROLLER,
    Excitation,
)

DEFAULT_DURATION = 60.0  # s


def add_parser(subcommands: argparse._SubParsersAction) -> None:
    parser = subcommands.add_parser(
        "record",
        help="record a sensor log from an env (identification excitation or a scenario)",
        description="Record a sensor log (the documented CSV or Parquet columns and the "
        "sidecar) from an env. Default: the identification excitation, a Fourier-series "
        "reference (Swevers et al. 1997) designed on the nominal model for a "
        "well-conditioned link-side regressor, inside the workspace and torque limits, "
        "plus a torque dither across the torsion modes, tracked by a motor PD. The plant "
        "and the sensors follow --env-kwargs (plant_scaling, unmodelled_friction, encoder, "
        "accelerometer, ...: a 'mystery arm'; kept in the log's provenance). With "
        "--scenario: that scenario's controller, state source and task instead. Note: at "
        "the envs' default physics step (0.5 ms) the simulated plant's effective joint "
        "damping is above the nominal D (semi-implicit Euler); --physics-dt 6.25e-5 "
        "brings it close.",
    )
    parser.add_argument(
        "env",
        metavar="ENV",
        help="an env id (TwoLinkElastic-v0); with --reference-only also a robot description file",
    )
    parser.add_argument(
        "--output",
        metavar="LOG",
        help="the log, .csv or .parquet (default ./record_out/<env>.csv); the sidecar "
        "<log>.yaml goes beside it",
    )
    parser.add_argument(
        "--duration", type=float, metavar="SECONDS", help=f"default {DEFAULT_DURATION:g}"
    )
    parser.add_argument("--seed", type=int, help="reset, design and dither seed (default 0)")
    parser.add_argument(
        "--env-kwargs",
        metavar="YAML",
        default="{}",
        help="env kwargs, e.g. '{plant_scaling: {stiffness: 1.1, link_mass: 0.8}}'",
    )
    parser.add_argument("--physics-dt", type=float, metavar="SECONDS", help="the physics step")
    parser.add_argument(
        "--controller",
        metavar="NAME",
        help=f"the tracking controller (default "
        f"{DEFAULT_CONTROLLER}, on rigid arms {RIGID_CONTROLLER}; with --scenario: the label "
        "of one of its controllers)",
    )
    parser.add_argument(
        "--controller-options", metavar="YAML", help="its options (default {omega: 20.0})"
    )
    parser.add_argument(
        "--state-source",
        metavar="NAME",
        help=f"the controller's state: an observer or "
        f"'true' (default {DEFAULT_SOURCE}; with --scenario: the label of one of its sources)",
    )
    parser.add_argument(
        "--scenario",
        metavar="PRESET_OR_YAML",
        help="record a scenario's controller, state "
        "source and task on ENV (one of its envs) instead of the excitation",
    )
    group = parser.add_argument_group("the excitation")
    defaults = Excitation()
    group.add_argument(
        "--period", type=float, default=defaults.period, help="s (default %(default)s)"
    )
    group.add_argument("--harmonics", type=int, default=defaults.harmonics)
    group.add_argument(
        "--fill", type=float, default=defaults.fill, help="of the workspace half-width"
    )
    group.add_argument(
        "--torque-fill", type=float, default=defaults.torque_fill, help="of the torque limits"
    )
    group.add_argument(
        "--dither-band",
        type=float,
        nargs=2,
        metavar=("LOW", "HIGH"),
        default=(2.0, 25.0),
        help="Hz (default 2 25)",
    )
    group.add_argument(
        "--dither-rms", type=float, default=0.03, help="of the torque limits (default 0.03)"
    )
    group.add_argument("--no-dither", action="store_true", help="the reference only")
    group.add_argument(
        "--reference",
        metavar="CSV",
        help="also write the excitation as a reference file "
        "(time, q_d, its derivatives, the dither torque per sample)",
    )
    group.add_argument(
        "--reference-only",
        action="store_true",
        help="write the reference file only (no simulation); ENV may be a robot description file",
    )
    parser.set_defaults(handler=run_record)


def excitation_of(args: argparse.Namespace) -> Excitation:
    from elastic_gym.envs.fourier import DitherOptions
    from elastic_gym.validation import errors_at, validated

    with errors_at("--dither-band/--dither-rms"):
        dither = (
            None
            if args.no_dither
            else validated(DitherOptions, {"band": list(args.dither_band), "rms": args.dither_rms})
        )
    for name in ("period", "fill", "torque_fill"):
        if not getattr(args, name) > 0.0:
            raise ValueError(f"--{name.replace('_', '-')} must be > 0")
    if not 0.0 < args.fill <= 1.0 or not 0.0 < args.torque_fill <= 1.0:
        raise ValueError("--fill and --torque-fill must be in (0, 1]")
    if args.harmonics < 1:
        raise ValueError("--harmonics must be >= 1")
    return Excitation(
        period=args.period,
        harmonics=args.harmonics,
        fill=args.fill,
        torque_fill=args.torque_fill,
        dither=dither,
    )


def env_kwargs_of(args: argparse.Namespace) -> dict[str, Any]:
    from elastic_gym.cli.common import yaml_mapping
    from elastic_gym.envs.config import checked_kwargs

    kwargs = yaml_mapping(args.env_kwargs, "--env-kwargs")
    if args.physics_dt is not None:
        kwargs["physics_dt"] = args.physics_dt
    return checked_kwargs(kwargs, ("--env-kwargs",))


def output_path(args: argparse.Namespace, env: str) -> Path:
    from elastic_gym.logs.io import log_kind

    name = Path(env).stem if env.endswith((".yaml", ".yml")) else env.rpartition("/")[2]
    path = Path(args.output) if args.output else Path("record_out") / f"{name}.csv"
    if log_kind(path) not in ("csv", "parquet"):
        raise ValueError(f"--output {path}: a log is written as .csv or .parquet")
    return path


def run_record(args: argparse.Namespace) -> int:
    if args.duration is not None and not args.duration > 0.0:
        raise ValueError("--duration must be > 0")
    if args.reference_only:
        return reference_only(args)
    from elastic_gym.envs.ids import registered_env_id

    env_id = registered_env_id(args.env)
    path = output_path(args, env_id)
    if args.scenario:
        return record_scenario(args, env_id, path)
    from elastic_gym.cli.common import yaml_mapping
    from elastic_gym.logs.record import record_excitation

    if args.reference and Path(args.reference).suffix != ".csv":
        raise ValueError(f"--reference {args.reference}: a reference file is a .csv")
    excitation = excitation_of(args)
    kwargs = env_kwargs_of(args)
    options = (
        None
        if args.controller_options is None
        else yaml_mapping(args.controller_options, "--controller-options")
    )
    duration = DEFAULT_DURATION if args.duration is None else args.duration
    start = time.perf_counter()
    log, design = record_excitation(
        env_id,
        duration,
        0 if args.seed is None else args.seed,
        kwargs,
        excitation,
        args.controller,
        options,
        args.state_source or DEFAULT_SOURCE,
    )
    written = write(path, log)
    if args.reference:
        written.append(
            write_reference(
                Path(args.reference), log.robot, design.task_options, duration, log.sample_time
            )
        )
    print(
        f"recorded {duration:g} s of {env_id} ({len(log)} samples) in "
        f"{time.perf_counter() - start:.1f} s; excitation: condition number "
        f"{design.condition_number:.3g} ({design.base_columns} base columns), rigid torque "
        f"up to {design.torque_ratio:.0%} of the limits"
    )
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


def write(path: Path, log) -> list[Path]:
    from elastic_gym.logs import write_log

    path.parent.mkdir(parents=True, exist_ok=True)
    return list(write_log(path, log))


def write_reference(path: Path, spec, task_options: dict, duration: float, dt: float) -> Path:
    from elastic_gym.logs.csv_format import write_csv_table
    from elastic_gym.logs.record import reference_table

    header, values = reference_table(spec, task_options, duration, dt)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_csv_table(path, header, values)
    return path


def reference_only(args: argparse.Namespace) -> int:
    """The excitation designed for ENV's nominal model, written as a reference file."""
    from elastic_gym.logs.record import design_for, robot_and_limits
    from elastic_gym.model import RobotModel
    from elastic_gym.robots.description import robot_from_description
    from elastic_gym.validation import per_joint_values

    if not args.reference:
        raise ValueError("--reference-only needs --reference CSV")
    if Path(args.reference).suffix != ".csv":
        raise ValueError(f"--reference {args.reference}: a reference file is a .csv")
    excitation = excitation_of(args)
    if args.env.endswith((".yaml", ".yml")):
        spec = robot_from_description(args.env)
        model = RobotModel(spec)
        limit = per_joint_values(spec.torque_limit, spec.n_joints, "torque_limit")
        dt = spec.control_dt
    else:
        spec, model, limit = robot_and_limits(args.env, env_kwargs_of(args))
        dt = spec.control_dt
    seed = 0 if args.seed is None else args.seed
    design = design_for(spec, model, limit, excitation, seed)
    duration = DEFAULT_DURATION if args.duration is None else args.duration
    path = write_reference(Path(args.reference), spec, design.task_options, duration, dt)
    print(
        f"excitation for {spec.name}: condition number {design.condition_number:.3g}, rigid "
        f"torque up to {design.torque_ratio:.0%} of the limits; wrote {path}"
    )
    return 0


def record_scenario(args: argparse.Namespace, env_id: str, path: Path) -> int:
    """ENV's entry of a scenario, with one of its controllers and state sources."""
    from elastic_gym.controllers.base import Controller
    from elastic_gym.evaluation.presets import list_presets, load_preset, load_scenario
    from elastic_gym.evaluation.scenario import resolve_class
    from elastic_gym.logs.record import run_closed_loop
    from elastic_gym.validation import lookup

    if args.reference or args.reference_only:
        raise ValueError("--reference writes the excitation's reference: not with --scenario")
    given = Path(args.scenario)
    if given.is_file():
        scenario = load_scenario(given)
    elif args.scenario in list_presets():
        scenario = load_preset(args.scenario)
    else:
        raise ValueError(
            f"--scenario {args.scenario!r}: neither a file nor a preset ({list_presets()})"
        )
    envs = {entry.id: entry for entry in scenario.envs}
    entry = lookup(envs, env_id, f"env of scenario {scenario.name!r}")
    controllers = {c.label: c for c in scenario.controllers}
    sources = {s.label: s for s in scenario.state_sources}
    controller = lookup(controllers, args.controller or next(iter(controllers)), "controller")
    source = lookup(sources, args.state_source or next(iter(sources)), "state source")
    kwargs = {**scenario.physics_kwargs(), **entry.kwargs, **env_kwargs_of(args)}
    duration = scenario.duration if args.duration is None else args.duration
    seed = scenario.seeds[0] if args.seed is None else args.seed
    start = time.perf_counter()
    law = controller.cls or controller.name
    if isinstance(law, str) and ":" in law:
        law = resolve_class(law, "controller class", (Controller,))
    log = run_closed_loop(
        env_id,
        kwargs,
        duration,
        seed,
        law,
        controller.options,
        source.name,
        source.options,
        provenance={"notes": f"scenario {scenario.name}"},
        reset_options=entry.reset_options,
    )
    written = write(path, log)
    print(
        f"recorded {duration:g} s of {env_id} ({len(log)} samples, {controller.label} on "
        f"{source.label}) in {time.perf_counter() - start:.1f} s"
    )
    print("wrote " + ", ".join(str(p) for p in written))
    return 0
