"""`elastic-gym observe LOG --observer NAME`: an observer run offline on a sensor log,
through the observer wrappers' own estimation loop; writes the estimate as a log of the
same format and, for a log with truth columns, the estimation error table."""

from __future__ import annotations

import argparse
import re
import time
from pathlib import Path

DEFAULT_OUTPUT = "observe_out"
DEFAULT_SETTLE = 0.1  # s


def add_parser(subcommands: argparse._SubParsersAction) -> None:
    parser = subcommands.add_parser(
        "observe",
        help="run an observer offline on a sensor log (CSV, Parquet, ROS 2 bag, MCAP)",
        description="Run an observer on a recorded sensor log, as the observer wrappers run "
        "it in the envs (bit for bit the online estimate on a log recorded from a "
        "simulation). Writes the estimate (theta, q, theta', q') as a log of the same "
        "format and, when the log has truth columns, the estimation error table. Nothing "
        "is written for a bad log, bad options or an estimate that diverges.",
    )
    parser.add_argument("log", metavar="LOG", help="the log (its sidecar <log>.yaml beside it)")
    parser.add_argument(
        "--observer",
        required=True,
        metavar="NAME",
        help="a registry name (deluca, ekf, finite-difference, ...) or module:Class",
    )
    parser.add_argument(
        "--options",
        metavar="YAML",
        help="the observer's options: a YAML file, or a YAML mapping such as '{bandwidth: 200}'",
    )
    parser.add_argument(
        "--model",
        metavar="MODEL.yaml",
        help="an identified model file (elastic-gym identify) the observer is built on "
        "(default: the log's nominal model)",
    )
    parser.add_argument("--sidecar", metavar="YAML", help="the log's sidecar (default <log>.yaml)")
    parser.add_argument(
        "--output", metavar="DIR", default=DEFAULT_OUTPUT, help=f"default ./{DEFAULT_OUTPUT}"
    )
    parser.add_argument(
        "--settle",
        type=float,
        default=DEFAULT_SETTLE,
        metavar="SECONDS",
        help=f"the error table's rms_settled leaves out the first SECONDS (default "
        f"{DEFAULT_SETTLE:g})",
    )
    parser.set_defaults(handler=run_observe)


def observer_options(text: str | None) -> dict:
    """`--options`: a YAML file's mapping, or a YAML mapping given inline."""
    from elastic_gym.cli.common import yaml_mapping

    if text is None:
        return {}
    path = Path(text)
    if path.suffix in (".yaml", ".yml") or path.is_file():
        if not path.is_file():
            raise FileNotFoundError(f"--options: no such file {text!r}")
        return yaml_mapping(path.read_text(), f"--options {text}")
    return yaml_mapping(text, "--options")


def load_model(path: str | None, log):
    """The observer's model: the log's nominal one, or the identified model file."""
    if path is None:
        return None
    file = Path(path)
    if not file.is_file():
        raise FileNotFoundError(f"--model: no such file {path!r}")
    try:
        from elastic_gym.model.identified import identified_robot_model
    except ImportError:
        raise ValueError(
            f"--model {path}: identified model files are not supported by this version "
            "(elastic_gym.model.identified is missing)"
        ) from None
    return identified_robot_model(file, log.nominal_model())


def file_label(observer: str) -> str:
    """A file-name-safe label of an observer name (`pkg.mod:MyObserver` -> `myobserver`)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", observer.rpartition(":")[2]).strip("-").lower()


def run_observe(args: argparse.Namespace) -> int:
    from elastic_gym import __version__
    from elastic_gym.logs import error_table, estimate_log, read_log, write_log
    from elastic_gym.logs.replay import ERROR_COLUMNS, estimate_as_log
    from elastic_gym.runtime.atomic import write_text

    log = read_log(args.log, args.sidecar)
    options = observer_options(args.options)
    model = load_model(args.model, log)
    if not args.settle >= 0.0:
        raise ValueError(f"--settle must be >= 0, got {args.settle}")
    start, cpu = time.perf_counter(), time.process_time()
    try:
        result = estimate_log(log, args.observer, model, options)
    except TypeError as exc:  # an option of the wrong type
        raise ValueError(str(exc)) from None
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    try:
        estimated = estimate_as_log(
            log,
            result,
            {
                "writer": "elastic-gym observe",
                "version": __version__,
                "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                "observer": {
                    "name": args.observer,
                    "options": options,
                    "model": args.model or "nominal",
                },
                "source_log": str(Path(args.log).resolve()),
            },
        )
    except ValueError as exc:  # the estimate diverged: nothing to write
        raise RuntimeError(str(exc)) from None
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    stem = f"{Path(args.log).stem}.{file_label(args.observer)}"
    path, side = write_log(output / f"{stem}.csv", estimated)
    written = [path, side]
    table = error_table(log, result, args.settle) if log.truth is not None else None
    if table is not None:
        lines = [",".join(ERROR_COLUMNS)]
        lines += [",".join(str(row[c]) for c in ERROR_COLUMNS) for row in table]
        written.append(write_text(output / f"{stem}.errors.csv", "\n".join(lines) + "\n"))
        written.append(write_text(output / f"{stem}.errors.md", markdown(table, args.settle)))
    print(
        f"{args.observer} on {args.log}: {len(log)} samples, {log.duration:.3f} s of log in "
        f"{wall:.3f} s ({log.duration / wall:.3g}x real time; {cpu:.3f} s of CPU)"
    )
    if table is not None:
        print(markdown(table, args.settle), end="")
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


def markdown(table: list[dict], settle: float) -> str:
    """The error table as markdown."""
    lines = [
        f"| column | unit | RMS error | max abs error | RMS after {settle:g} s |",
        "|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['column']} | {r['unit']} | {r['rms']:.3e} | {r['max_abs']:.3e} | "
        f"{r['rms_settled']:.3e} |"
        for r in table
    ]
    return "\n".join(lines) + "\n"
