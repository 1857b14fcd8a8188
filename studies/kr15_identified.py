"""The papers' experiment, closed: a KR15 the model does not know, identified from its log,
then De Luca's observer and eq. (13) on the nominal against the identified model.

1. A "mystery" KR15 (`MYSTERY`: K, B and link masses off by 15-20 % per joint) records a
   60 s identification log (`studies/identification.py`'s recorder: the compiled RK4 and
   the envs' default sensors; a multi-sine reference plus a 2-25 Hz torque dither).
2. `identify` fits it from the log's columns alone (`model.yaml`, `report.md`).
3. `compare` runs eq. (13) (INVDYN feedforward + full-state feedback, omega 30 rad/s) on
   the true state and on De Luca's implementable observer (eq. (12)) on the mystery plant
   (KR15Elastic-v0 with its `plant_scaling`, the comparisons' 1/16 ms physics), with the
   model those build on being the nominal one, the identified one, or the plant's own (an
   oracle), on the paper's 30 degree move of axis 1 and a three-axis motion (5 seeds).

Writes ``docs/results/identification/kr15.{md,csv,png}`` and the identification's report
into ``docs/results/identification/kr15_identification/``.
``python studies/kr15_identified.py [--out kr15_out] [--report]``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from elastic_gym.evaluation import Scenario, compare
from elastic_gym.identification.identify import identify, write_identification
from elastic_gym.logs import read_log
from elastic_gym.model.identified import load_identified_model
from elastic_gym.robots.catalog import get_robot

sys.path.insert(0, str(Path(__file__).resolve().parent))
from identification import RESULTS, record

MYSTERY = {
    "stiffness": [0.8, 1.2, 0.85],
    "motor_inertia": [1.15, 0.85, 1.2],
    "link_mass": [1.2, 0.85, 1.15],
}
NO_FRICTION = {"coulomb": [0.0, 0.0, 0.0], "viscous": [0.0, 0.0, 0.0]}
MODELS = ("nominal", "identified", "plant")


def identified_scaling(path: Path) -> dict:
    """The identified model file as factors on the nominal model (a model error)."""
    file = load_identified_model(path)
    spec = get_robot(file.robot)
    return {
        "stiffness": (file.values("stiffness") / np.asarray(spec.stiffness)).tolist(),
        "damping": (file.values("damping") / np.asarray(spec.damping)).tolist(),
        "motor_inertia": (file.values("motor_inertia") / np.asarray(spec.motor_inertia)).tolist(),
        "link_mass": file.values("link_mass_scale").tolist(),
    }


def scenario(scaling: dict, seeds: int) -> Scenario:
    move = {
        "task": "tracking",
        "task_options": {
            "start": [0.0, 0.0, 0.5],
            "waypoints": [[0.5235987755982988, 0.0, 0.5], [0.0, 0.0, 0.5]],
            "move_time": 1.0,
            "dwell_time": 0.5,
        },
    }
    three_axes = {"task": "tracking", "task_options": {"n_moves": 2, "move_time": 1.0}}
    mystery = {"plant_scaling": MYSTERY}
    return Scenario.model_validate(
        {
            "name": "kr15-identified",
            "duration": 3.0,
            "seeds": list(range(seeds)),
            "envs": [
                {
                    "id": "elastic_gym/KR15Elastic-v0",
                    "label": "axis1-30deg",
                    "kwargs": {**move, **mystery},
                },
                {
                    "id": "elastic_gym/KR15Elastic-v0",
                    "label": "three-axes",
                    "kwargs": {**three_axes, **mystery},
                },
            ],
            "model_errors": [
                {"label": "nominal"},
                {"label": "identified", **scaling},
                {"label": "plant", **MYSTERY},
            ],
            "controllers": [
                {
                    "name": "feedforward-state-feedback",
                    "label": "eq13",
                    "options": {"omega": 30.0},
                }
            ],
            "state_sources": ["true", {"name": "deluca", "label": "deluca"}],
        }
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("kr15_out"))
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--seed", type=int, default=15)
    parser.add_argument("--report", action="store_true", help="only rebuild the table/figure")
    args = parser.parse_args(argv)
    log_dir, identified = args.out / "log", args.out / "identified"
    if not args.report:
        if not (log_dir / "plant0.csv").exists():
            plant = {"plant_scaling": MYSTERY, "unmodelled_friction": NO_FRICTION}
            record("kr15", [plant], args.seconds, args.seed, log_dir)
        write_identification(identify(read_log(log_dir / "plant0.csv")), identified)
        result = compare(
            scenario(identified_scaling(identified / "model.yaml"), args.seeds),
            output_dir=args.out / "compare",
            overwrite=True,
            plots=False,
        )
        shutil.copyfile(args.out / "compare" / "summary.csv", args.out / "summary.csv")
        del result
    publish(args.out, identified)
    return 0


def _rows(path: Path) -> list[dict]:
    import csv

    with path.open() as handle:
        return list(csv.DictReader(handle))


def publish(out: Path, identified: Path) -> None:
    """docs/results/identification/kr15.md, kr15.csv, kr15.png and the identification."""
    rows = _rows(out / "summary.csv")
    RESULTS.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(out / "summary.csv", RESULTS / "kr15.csv")
    target = RESULTS / "kr15_identification"
    target.mkdir(exist_ok=True)
    for name in ("report.md", "identification.png"):
        shutil.copyfile(identified / name, target / name)
    # the model file names its schema relative to the repository, not to this machine
    text = (identified / "model.yaml").read_text().split("\n", 1)[1]
    schema = "../../../../elastic_gym/schemas/model.json"
    (target / "model.yaml").write_text(f"# yaml-language-server: $schema={schema}\n{text}")
    metrics = (
        ("track_rms", "tracking RMS (rad)"),
        ("track_max", "max tracking error (rad)"),
        ("est_rms_q", "q estimation RMS (rad)"),
        ("est_rms_dq", "q' estimation RMS (rad/s)"),
    )
    lines = [
        "| motion | state | model | " + " | ".join(label for _, label in metrics) + " |",
        "|---|---|---|" + "---:|" * len(metrics),
    ]
    for row in rows:
        cells = []
        for key, _ in metrics:
            estimated = key.startswith("est_")
            value = row.get(key)
            shown = (
                "—"
                if (estimated and row["source"] == "true") or not value
                else f"{float(value):.3g}"
            )
            cells.append(shown)
        source = "De Luca estimate" if row["source"] == "deluca" else "true state"
        lines.append(
            f"| {row['env']} | {source} | {row['model_error']} | " + " | ".join(cells) + " |"
        )
    (RESULTS / "kr15.md").write_text("\n".join(lines) + "\n")
    figure = Figure(figsize=(9, 3.6), constrained_layout=True)
    axes = figure.subplots(1, 2)
    envs = list(dict.fromkeys(row["env"] for row in rows))
    width = 0.8 / len(MODELS)
    panels = (
        ("track_rms", "eq. (13): tracking RMS (rad)", ("true", "deluca")),
        ("est_rms_q", "De Luca observer: q estimation RMS (rad)", ("deluca",)),
    )
    for ax, (key, label, sources) in zip(axes, panels, strict=True):
        groups = [(env, source) for env in envs for source in sources]
        for m, model in enumerate(MODELS):
            values = []
            for env, source in groups:
                match = [
                    r
                    for r in rows
                    if r["env"] == env and r["source"] == source and r["model_error"] == model
                ]
                values.append(float(match[0][key]) if match and match[0][key] else np.nan)
            ax.bar(np.arange(len(groups)) + (m - 1) * width, values, width, label=model)
        names = {"true": "true state", "deluca": "De Luca"}
        ax.set_xticks(np.arange(len(groups)), [f"{e}\n{names[s]}" for e, s in groups], fontsize=7)
        ax.set_yscale("log")
        ax.set_title(label, fontsize=9)
    handles, labels = axes[0].get_legend_handles_labels()
    figure.legend(
        handles,
        labels,
        loc="outside lower center",
        ncol=3,
        fontsize=8,
        title="the model eq. (13) and the observer build on",
        title_fontsize=8,
    )
    figure.suptitle(
        "A KR15 whose K, B and link masses the nominal model does not know", fontsize=10
    )
    figure.savefig(RESULTS / "kr15.png", dpi=90)
    print("\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
