"""The robustness study of policies: PPO and RecurrentPPO trained on the nominal plant and
with domain randomization, next to eq. (13), eq. (13) with integral action and motor PD,
on eight plants the model does not know.

    python studies/robust_study.py               # train what is missing, evaluate, report
    python studies/robust_study.py --report      # no training: evaluate finished runs, report
    python studies/robust_study.py --commands    # the elastic-gym train command of each run
    python studies/robust_study.py --runs DIR    # run folders DIR/<row>/seed<k>

The training, evaluation and report machinery is the RL study's (``rl_study.py``: resumed
training, cached evaluations, learning curves); this file holds what differs:

1. Training: ``TRAINING``, one line per row: training seeds, hyper-parameter file (a bare
   name is a shipped file of ``elastic_gym/training/hyperparams/``; None: the algorithm's
   shipped defaults) and the ``elastic-gym train`` arguments, parsed by that command's own
   parser, so that a row's run is exactly the command ``--commands`` prints. The budget is
   the file's ``n_timesteps`` unless the arguments give ``--steps``. Run folders
   ``<runs>/<row>/seed<k>`` (default ``runs/robust_study``); a finished one is skipped.
2. Evaluation: every policy (deterministic, its final model) and every loop of
   ``CLASSICAL`` on ``EVAL_EPISODES`` fresh episodes (seeds 100000 ...: never a training
   or learning-curve seed) of the comparison's tracking task on each plant of ``PLANTS``:
   every plant kwarg at the env's default (no randomization) but the one changed.
3. Report into ``--out`` (default ``docs/results/robust_study/``): ``table.md`` / ``table.csv``
   (loop x source x plant: the RMS over the episodes' samples, mean and range over
   training seeds), ``evaluations.csv``, ``targets.md`` (the issue's four targets, computed
   from the evaluations), ``robust_rms.png``, ``rows.md``, ``runs.md`` (the runs
   evaluated and what they were trained with beyond the table), ``stamp.md``, ``curves.csv`` and
   ``learning_curves.png``.
"""

from __future__ import annotations

import copy
import csv
import datetime
import json
import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from functools import cache, cached_property
from pathlib import Path

import numpy as np
import yaml

import elastic_gym
from elastic_gym.envs.config import PER_ARM_KEYS, EnvConfig
from elastic_gym.training import TrainConfig
from elastic_gym.training.config import merged_hyperparams
from elastic_gym.training.run_folder import FINISHED, RunFolder

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the RL study beside this file
from rl_study import (
    EQ13,
    EVAL_EPISODES,
    TASK,
    Study,
    Target,
    row_rms,
    run,
    seed_rms,
    write_targets,
)

INTEGRAL = "integral-state-feedback"
LOAD_IDENTIFIED = {"load_identification": "shared"}  # one scale for all links, the plants'
ENCODERS = "finite-difference"  # motor encoders, filtered differences: no K, B or accelerometer
TRAIN_COMMAND = (sys.executable, "-m", "elastic_gym.cli", "train")  # the public command
HYPERPARAMS = Path(elastic_gym.__file__).resolve().parent / "training" / "hyperparams"

# key, training seeds, hyper-parameter file (None: the shipped one), `elastic-gym train` arguments
TRAINING = (
    ("ppo-true-nominal", 1, None, "--algo ppo --state true"),
    ("ppo-true-robust", 1, "ppo-robust.yaml", "--algo ppo --state true"),
    ("ppo-deluca-nominal", 1, None, "--algo ppo --state deluca"),
    ("ppo-deluca-robust", 3, "ppo-robust.yaml", "--algo ppo --state deluca"),
    (
        "rppo-deluca-robust",
        3,
        "recurrentppo-deluca-robust.yaml",
        "--algo recurrentppo --state deluca",
    ),
    ("rppo-sensors-nominal", 1, None, "--algo recurrentppo --state sensors --frame-stack 1"),
    (
        "rppo-sensors-robust",
        3,
        "recurrentppo-robust.yaml",
        "--algo recurrentppo --state sensors --frame-stack 1",
    ),
    (
        "rppo-sensors-distilled",
        3,
        "recurrentppo-distilled.yaml",
        "--algo recurrentppo --state sensors --frame-stack 1",
    ),
    (
        "residual-integral-robust",
        3,
        "ppo-residual-robust.yaml",
        f"--algo ppo --state deluca --residual {INTEGRAL}",
    ),
)

# every per-arm plant kwarg at the env's default: no randomization, the nominal plant
DEFAULT_PLANT = {key: EnvConfig.model_fields[key].default for key in (*PER_ARM_KEYS, "per_arm")}
CHANGES = {  # name -> (label, the change from the default plant)
    "nominal": ("nominal", {}),
    "mass0.7": ("link mass ×0.7", {"plant_scaling": {"link_mass": 0.7}}),
    "mass1.3": ("link mass ×1.3", {"plant_scaling": {"link_mass": 1.3}}),
    "coulomb1%": ("Coulomb 1 %", {"unmodelled_friction": {"coulomb": 0.01}}),
    "coulomb3%": ("Coulomb 3 %", {"unmodelled_friction": {"coulomb": 0.03}}),
    "K0.9": ("K ×0.9", {"plant_scaling": {"stiffness": 0.9}}),
    "B1.1": ("B ×1.1", {"plant_scaling": {"motor_inertia": 1.1}}),
    "delay1ms": ("sensor delay 1 ms", {"sensor_delay": 1}),  # control periods of 1 ms
}
PLANTS = {name: {**DEFAULT_PLANT, **change} for name, (_, change) in CHANGES.items()}
PLANT_LABELS = {name: label for name, (label, _) in CHANGES.items()}

CLASSICAL = (  # (controller, label, state sources[, options])
    (EQ13, "eq. (13)", ("true", "deluca")),
    (INTEGRAL, "eq. (13) + integral action", ("true", "deluca")),
    (
        INTEGRAL,
        "eq. (13) + integral action, load identified",
        ("true", "deluca"),
        LOAD_IDENTIFIED,
    ),
    ("motor-pd", "motor PD", ("true", "deluca", ENCODERS)),
)
SOURCES = {"true": "true", "deluca": "De Luca", ENCODERS: "encoders", "sensors": "raw sensors"}
ALGO_LABELS = {"ppo": "PPO", "recurrentppo": "RecurrentPPO"}


def hyperparams_path(name: str) -> str:
    """A bare file name is a shipped hyper-parameter file; a path is itself (relative to
    the working directory where it lies below it)."""
    path = HYPERPARAMS / name if Path(name).name == name else Path(name).resolve()
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return str(path)


@cache
def printed_config(argv: tuple[str, ...]) -> dict:
    """The config ``elastic-gym train <argv> --print-config`` prints (one run's mapping of
    `TrainConfig` fields), from one subprocess per distinct ``argv`` (the command's
    answer depends on its arguments and the shipped hyper-parameter files only)."""
    output = subprocess.run(
        [*TRAIN_COMMAND, *argv, "--print-config"], capture_output=True, text=True, check=True
    ).stdout
    (config,) = yaml.safe_load(output)
    return config


@dataclass(frozen=True)
class Row:
    """A policy row: ``elastic-gym train`` ``arguments`` with ``hyperparams_file`` on
    ``seeds``; ``steps`` (None: the arguments' or the file's) overrides the budget."""

    key: str
    seeds: tuple[int, ...]
    hyperparams_file: str | None
    arguments: str
    steps: int | None = None
    plants: tuple[str, ...] = tuple(PLANTS)
    eval_task: dict = field(default_factory=lambda: TASK)

    def argv(self, seed: int, runs: Path) -> list[str]:
        argv = shlex.split(self.arguments)
        if self.hyperparams_file is not None:
            argv += ["--hyperparams-file", hyperparams_path(self.hyperparams_file)]
        if self.steps is not None:
            argv += ["--steps", str(self.steps)]
        return [*argv, "--seeds", str(seed), "--out", str(runs / self.key / f"seed{seed}")]

    def config(self, seed: int, runs: Path) -> TrainConfig:
        """What ``elastic-gym train <argv> --print-config`` says the command trains."""
        return TrainConfig.from_dict(copy.deepcopy(printed_config(tuple(self.argv(seed, runs)))))

    @cached_property
    def _config(self) -> TrainConfig:
        return self.config(self.seeds[0], Path("runs"))

    @property
    def state(self) -> str:
        return self._config.state

    @property
    def algo(self) -> str:
        return self._config.algo

    @property
    def env_id(self) -> str:
        return self._config.env_id

    @property
    def label(self) -> str:
        if self._config.action:
            kind = "residual on eq. (13) + integral action"
        elif self._config.settings()[0].distill is not None:
            kind = "distilled from the plant teacher (DAgger)"
        else:
            kind = "pure RL"
        training = "randomized" if self.hyperparams_file else "nominal"
        return f"{ALGO_LABELS[self.algo]}, {kind}, trained {training}"


ROWS = tuple(Row(key, tuple(range(n)), file, arguments) for key, n, file, arguments in TRAINING)


def command(row: Row, seed: int, runs: Path) -> str:
    """The ``elastic-gym train`` command of one run of ``row``."""
    return shlex.join(["elastic-gym", "train", *row.argv(seed, runs), "--no-progress"])


# ---------------------------------------------------------------- report
def table_order(records: list[dict]) -> list[str]:
    """Row keys grouped by state source (true, De Luca, encoders, raw sensors), classical
    loops first."""
    keys = list(dict.fromkeys(r["row"] for r in records))
    first = {key: next(r for r in records if r["row"] == key) for key in keys}
    sources = list(SOURCES)
    return sorted(
        keys,
        key=lambda k: (
            sources.index(first[k]["state"]) if first[k]["state"] in sources else len(sources),
            first[k]["algo"] != "",
        ),
    )


def table(records: list[dict]) -> list[dict]:
    """One line per loop x source: per plant the mean over training seeds of each seed's
    RMS over the episodes, and the seeds' min and max."""
    lines = []
    for key in table_order(records):
        mine = [r for r in records if r["row"] == key]
        first = mine[0]
        seeds = sorted({r["seed"] for r in mine})
        line = {
            "row": key,
            "loop": first["label"],
            "state": SOURCES.get(first["state"], first["state"]),
            "training seeds": len(seeds) if first["algo"] else "",
        }
        for plant in PLANTS:
            per_seed = seed_rms(mine, key, plant)
            line[plant] = float(np.mean(per_seed)) if per_seed else ""
            line[f"{plant} min"] = min(per_seed) if len(per_seed) > 1 else ""
            line[f"{plant} max"] = max(per_seed) if len(per_seed) > 1 else ""
        steps = [float(r["policy_steps"]) for r in mine if r["policy_steps"]]
        walls = [float(r["wall_time"]) for r in mine if r["wall_time"]]
        line["policy steps"] = round(np.mean(steps)) if steps else ""
        line["training time [s]"] = round(np.mean(walls)) if walls else ""
        lines.append(line)
    return lines


def _cell(line: dict, plant: str) -> str:
    if line[plant] == "":
        return ""
    text = f"{line[plant]:.2e}"
    if line[f"{plant} min"] != "":
        text += f" ({line[f'{plant} min']:.1e} – {line[f'{plant} max']:.1e})"
    return text


def write_table(lines: list[dict], out: Path) -> None:
    with open(out / "table.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, list(lines[0]))
        writer.writeheader()
        writer.writerows(lines)
    head = ["loop", "state", "training seeds", *PLANT_LABELS.values()]
    head += ["policy steps", "training time [s]"]
    text = [
        "| " + " | ".join(head) + " |",
        "|---|---|" + "---:|" * (len(head) - 2),
    ]
    for line in lines:
        cells = [line["loop"], line["state"], str(line["training seeds"])]
        cells += [_cell(line, plant) for plant in PLANTS]
        cells += [str(line["policy steps"]), str(line["training time [s]"])]
        text.append("| " + " | ".join(cells) + " |")
    (out / "table.md").write_text("\n".join(text) + "\n")


FIFTEEN_MINUTES = 900.0  # s


def targets(records: list[dict]) -> list[Target]:
    """The four targets of the study (each with its bound computed from the evaluations);
    the first holds for randomized pure RL on De Luca, PPO and RecurrentPPO each, the
    second for the raw-sensor RecurrentPPO trained by RL and the one distilled."""

    def rms(key: str, plant: str) -> float:
        return row_rms(records, key, plant)

    def wall(key: str) -> float:
        walls = [float(r["wall_time"]) for r in records if r["row"] == key and r["wall_time"]]
        return float(np.mean(walls)) if walls else float("nan")

    integral, fd, eq13 = f"{INTEGRAL}-deluca", f"motor-pd-{ENCODERS}", f"{EQ13}-deluca"
    rppo, residual = "rppo-sensors-robust", "residual-integral-robust"
    distilled = "rppo-sensors-distilled"
    integral_rule = "eq. (13) + integral action on De Luca"
    checks = []
    for robust, algo in (("ppo-deluca-robust", "PPO"), ("rppo-deluca-robust", "RecurrentPPO")):
        name = f"randomized {algo} on De Luca"
        checks += [
            Target(
                f"{name}, link mass ×1.3",
                rms(robust, "mass1.3"),
                rms(integral, "mass1.3"),
                integral_rule,
                strict=True,
            ),
            Target(
                f"{name}, Coulomb 1 %",
                rms(robust, "coulomb1%"),
                rms(integral, "coulomb1%"),
                integral_rule,
                strict=True,
            ),
            Target(f"{name}, nominal", rms(robust, "nominal"), 7e-4, "7e-4 rad"),
        ]
    for key, name in ((rppo, "RecurrentPPO"), (distilled, "RecurrentPPO distilled")):
        for plant in ("K0.9", "B1.1"):
            label = PLANT_LABELS[plant]
            checks += [
                Target(
                    f"randomized {name} on raw sensors, {label}, vs motor PD",
                    rms(key, plant),
                    rms(fd, plant),
                    "motor PD on the encoders",
                    strict=True,
                ),
                Target(
                    f"randomized {name} on raw sensors, {label}, vs eq. (13)",
                    rms(key, plant),
                    rms(eq13, plant) / 3,
                    "eq. (13) on De Luca / 3",
                    strict=True,
                ),
            ]
    checks += [
        Target(
            "randomized residual on eq. (13) + integral action, De Luca, link mass ×1.3",
            rms(residual, "mass1.3"),
            0.5 * rms(integral, "mass1.3"),
            "0.5 x " + integral_rule,
        ),
        Target(
            "randomized residual on eq. (13) + integral action, De Luca, nominal",
            rms(residual, "nominal"),
            1.2 * rms(integral, "nominal"),
            "1.2 x " + integral_rule,
        ),
        Target(
            "nominal PPO on the true state, nominal",
            rms("ppo-true-nominal", "nominal"),
            2e-4,
            "2e-4 rad",
        ),
        Target(
            "nominal PPO on the true state, training wall time",
            wall("ppo-true-nominal"),
            FIFTEEN_MINUTES,
            "15 min",
            unit="s",
        ),
    ]
    return checks


def plot(lines: list[dict], out: Path) -> None:
    """``robust_rms.png``: tracking RMS per plant (bars), one group per loop x source,
    log scale; the whiskers span the training seeds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(max(8.0, 1.1 * len(lines) + 2), 5.5))
    width = 0.8 / len(PLANTS)
    colors = plt.get_cmap("tab10")
    for index, plant in enumerate(PLANTS):
        x, height, low, high = [], [], [], []
        for group, line in enumerate(lines):
            if line[plant] == "":
                continue
            x.append(group - 0.4 + (index + 0.5) * width)
            height.append(line[plant])
            several = line[f"{plant} min"] != ""
            # the mean of equal seeds' RMS may round past their min or max: no whisker then
            low.append(max(line[plant] - line[f"{plant} min"], 0.0) if several else 0.0)
            high.append(max(line[f"{plant} max"] - line[plant], 0.0) if several else 0.0)
        if not x:
            continue
        ax.bar(
            x,
            height,
            width,
            yerr=[low, high],
            color=colors(index),
            label=PLANT_LABELS[plant],
            error_kw={"elinewidth": 0.8},
        )
    ax.set_yscale("log")
    ax.set_xticks(range(len(lines)))
    ax.set_xticklabels(
        [f"{line['loop']}\n[{line['state']}]".replace(", trained", ",\ntrained") for line in lines],
        rotation=35,
        ha="right",
        fontsize=7,
    )
    ax.set_ylabel("link tracking RMS [rad]")
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=4, loc="upper left")
    ax.set_title("Tracking RMS per plant (TwoLinkElastic; whiskers: range over training seeds)")
    fig.tight_layout()
    fig.savefig(out / "robust_rms.png", dpi=110)
    plt.close(fig)


def stamp(out: Path) -> None:
    """``stamp.md``: the version, commit and date of the report, and its command."""
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    today = datetime.datetime.now(datetime.UTC).date().isoformat()
    (out / "stamp.md").write_text(
        f"elastic-gym {elastic_gym.__version__} (commit `{commit}`), {today}; "
        f"regenerate: `python studies/robust_study.py` (`--report` from the saved "
        f"evaluations, `--runs DIR` for other run folders).\n"
    )


def write_rows(out: Path) -> None:
    """``rows.md``: the training table (``TRAINING``) as the report shows it."""
    text = ["| row | training seeds | hyper-parameter file | `elastic-gym train` arguments |"]
    text.append("|---|---:|---|---|")
    for row in ROWS:
        file = f"`{row.hyperparams_file}`" if row.hyperparams_file else "shipped default"
        text.append(f"| `{row.key}` | {len(row.seeds)} | {file} | `{row.arguments}` |")
    (out / "rows.md").write_text("\n".join(text) + "\n")


def differences(row: Row, seed: int, runs: Path) -> list[str]:
    """What the finished run of ``row`` in ``runs`` was trained with that the table's
    command would not have given it: the names of the differing config fields, resolved
    action and observation configs and hyper-parameters."""
    saved = RunFolder(Path(row.config(seed, runs).out_dir)).read_config()
    expected = row.config(seed, runs)
    names = [
        name
        for name in ("algo", "state", "env_id", "total_steps", "env_kwargs", "observer_options")
        if getattr(saved, name) != getattr(expected, name)
    ]
    if expected.state == "sensors" and saved.frame_stack != expected.frame_stack:
        names.append("frame_stack")
    try:
        settings, _ = expected.settings()
    except ValueError:  # the table's file does not exist (yet)
        return [*names, f"{expected.hyperparams_file} (not found)"]
    mine = saved.policy_configs(saved.settings()[0])
    theirs = expected.policy_configs(settings)
    names += [
        name
        for name, a, b in zip(("action", "observation"), mine, theirs, strict=True)
        if a.to_dict() != b.to_dict()
    ]
    shipped = merged_hyperparams(
        expected.algo, expected.env_id, expected.hyperparams, expected.hyperparams_file
    )
    keys = sorted(set(shipped) | set(saved.hyperparams))
    changed = [key for key in keys if shipped.get(key) != saved.hyperparams.get(key)]
    return names + [key for key in changed if key not in names]  # env_kwargs is both


def write_runs(rows, runs: Path, out: Path) -> None:
    """``runs.md``: every finished run evaluated, with what it was trained with beyond the
    table's command (field names of `differences`). A run whose folder is not under
    ``runs`` keeps its line of the earlier ``runs.md`` (its evaluations stay in
    ``evaluations.csv`` too), so a report on another machine adds runs without losing any."""
    earlier = {}
    if (out / "runs.md").exists():
        for line in (out / "runs.md").read_text().splitlines()[2:]:
            cells = [cell.strip() for cell in line.split("|")]
            earlier[(cells[1].strip("`"), cells[2])] = line
    text = [
        "| row | seed | policy steps | training time [s] | features | differs from the table in |"
    ]
    text.append("|---|---:|---:|---:|---|---|")
    for row in rows:
        for seed in row.seeds:
            folder = RunFolder(Path(row.config(seed, runs).out_dir))
            if not folder.finished:
                if (row.key, str(seed)) in earlier:
                    text.append(earlier[(row.key, str(seed))])
                continue
            summary = json.loads((folder.path / FINISHED).read_text())
            features = folder.read_config().observation.get("features")
            features = ", ".join(features) if features else "default"
            text.append(
                f"| `{row.key}` | {seed} | {summary['policy_steps']} | "
                f"{summary['wall_time']:.0f} | {features} | "
                f"{', '.join(differences(row, seed, runs)) or '—'} |"
            )
    (out / "runs.md").write_text("\n".join(text) + "\n")


def report(records: list[dict], out: Path, rows, runs: Path) -> list[str]:
    """The robustness study's files: table, targets, figure, training rows, the runs
    evaluated and the stamp."""
    lines = table(records)
    write_table(lines, out)
    write_targets([target.line() for target in targets(records)], out)
    plot(lines, out)
    write_rows(out)
    write_runs(rows, runs, out)
    stamp(out)
    files = ["table.md", "table.csv", "targets.md", "robust_rms.png", "rows.md", "runs.md"]
    return [*files, "stamp.md"]


ROBUST_STUDY = Study(
    "robustness study of policies",
    __doc__.split("\n\n")[0],
    ROWS,
    PLANTS,
    CLASSICAL,
    report,
    "runs/robust_study",
    "docs/results/robust_study",
    zero_offset=False,
    eval_episodes=EVAL_EPISODES,
    command=command,
)

if __name__ == "__main__":
    run(ROBUST_STUDY)
