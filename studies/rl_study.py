"""The RL study of the README: RL policies on the true state, on estimates and on raw
sensors, next to eq. (13), eq. (13) with integral action and motor PD on the same sources.

    nohup python studies/rl_study.py > rl_study.log 2>&1 &    # the whole study, background
    python studies/rl_study.py --report                         # tables + figures only

Steps (each skips what an earlier invocation finished, so an interrupted study resumes
where it stopped; ``--fresh`` starts over):

1. Training: every run of ``ROWS`` (row x training seed; a row's first seeds first) with
   `elastic_gym.training.train`, the shipped hyper-parameters of its algorithm
   (``elastic_gym/training/hyperparams/``) and the row's own policy steps (fewer than the
   shipped 400 k where the budget demanded: the README says which and why), one run at a
   time, into ``--runs``
   (default ``runs/rl_study/<row>/seed<k>``): each run folder holds its learning curve
   (``learning_curve.csv``: return and tracking RMS vs policy steps and wall time).
2. Evaluation: every policy (deterministic, its final model) and every classical
   controller on ``EVAL_EPISODES`` fresh episodes (seeds ``EVAL_SEED`` ...: never a
   training or learning-curve episode) of the comparison's tracking task (the
   ``default`` preset of ``elastic-gym compare``: 2 moves of 0.8 s, 0.5 s dwell, 3 s
   episodes), on the nominal plant and on links 30 % heavier than the model
   (``plant_scaling={"link_mass": 1.3}``); the classical controllers run through the same
   policy stack (a residual action kind with a zero action is its base controller).
   Tracking RMS as the comparison's ``track_rms``: sqrt(mean |q - q_d|^2), norm over the
   joints, at the policy rate (100 Hz).
3. Report, into ``--out`` (default ``docs/results/rl_study/``): ``table.md`` / ``table.csv`` (per
   row: mean over training seeds of the RMS over the evaluation episodes, and the range
   over training seeds), ``evaluations.csv`` (every run x plant x episode),
   ``targets.md`` (the targets of the study: measured, bound, met or missed),
   ``curves.csv`` (every learning-curve row of every run) and ``learning_curves.png``
   (tracking RMS and return vs policy steps and vs wall time; mean and min-max over
   training seeds).

Physics: the envs' default step (0.5 ms for TwoLinkElastic), as in training, so the
exact-model classical rows are partly integrator error (``elastic-gym compare`` runs at
1/16 ms, where eq. (13) tracks better); every row of the table shares it.

The log has one line per finished step with its wall time. Training runs use
single-threaded torch; ``batches`` in the hyper-parameters decides how many processes a
run uses.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from gymnasium.vector import AutoresetMode

from elastic_gym.policy import PolicySpec, build_policy_env
from elastic_gym.training import TrainConfig, load_run, train
from elastic_gym.training.rollouts import Evaluation, evaluate_arms
from elastic_gym.training.run_folder import CURVE_FILE, FINISHED
from elastic_gym.training.trained import evaluate_run

TWO_LINK = "elastic_gym/TwoLinkElastic-v0"
KR15 = "elastic_gym/KR15Elastic-v0"
TASK = {"task": "tracking", "task_options": {"n_moves": 2, "move_time": 0.8, "dwell_time": 0.5}}
PLANTS = {
    "nominal": {"plant_scaling": {"link_mass": 1.0}},  # explicit: overrides a run's own
    "mass+30%": {"plant_scaling": {"link_mass": 1.3}},
}
EVAL_EPISODES = 10
EVAL_SEED = 100_000
EQ13 = "feedforward-state-feedback"
PLAIN_RESIDUAL = {"kind": "residual", "residual": EQ13, "residual_deadzone": 0.0}
RESIDUAL = {**PLAIN_RESIDUAL, "residual_deadzone": 0.2}  # the default: zero while |a| <= 0.2


STEPS = 400_000  # policy steps per study run: the shipped default of PPO


@dataclass(frozen=True)
class Row:
    """One policy configuration of the table, trained with ``len(seeds)`` seeds for
    ``steps`` policy steps on ``train_env`` (env kwargs, e.g. a heavier plant)."""

    key: str
    label: str
    state: str
    seeds: tuple[int, ...]
    algo: str = "ppo"
    env_id: str = TWO_LINK
    action: dict = field(default_factory=dict)
    frame_stack: int = 1
    train_env: dict = field(default_factory=dict)
    steps: int = STEPS
    hyperparams: dict = field(default_factory=dict)
    eval_task: dict = field(default_factory=lambda: TASK)
    plants: tuple[str, ...] = tuple(PLANTS)

    def config(self, seed: int, runs: Path) -> TrainConfig:
        return TrainConfig(
            env_id=self.env_id,
            algo=self.algo,
            state=self.state,
            seed=seed,
            out_dir=str(runs / self.key / f"seed{seed}"),
            action=self.action,
            frame_stack=self.frame_stack,
            env_kwargs=self.train_env,
            total_steps=self.steps,
            hyperparams=self.hyperparams,
            eval_freq=max(self.steps // 10, 10_000),
            eval_episodes=5,
        )


HEAVY = PLANTS["mass+30%"]
BOTH_PLANTS = {"batches": [{}, HEAVY]}  # half the arms on each plant (two worker processes)
ROWS = (  # the budget (about 2 cores for 85 min) and what it cut: see the README
    Row("pure-true", "pure RL (motor offsets)", "true", (0, 1, 2)),
    Row("pure-deluca", "pure RL (motor offsets)", "deluca", (0, 1, 2)),
    Row(
        "pure-sensors", "pure RL (motor offsets), 4 stacked frames", "sensors", (0,), frame_stack=4
    ),
    Row(
        "residual-deluca-plain",
        "residual on eq. (13), no deadzone",
        "deluca",
        (0,),
        action=PLAIN_RESIDUAL,
        steps=60_000,
    ),
    Row("residual-deluca", "residual on eq. (13)", "deluca", (0,), action=RESIDUAL, steps=60_000),
    Row(
        "residual-deluca-heavy",
        "residual on eq. (13), trained on +30 % mass",
        "deluca",
        (0,),
        action=RESIDUAL,
        train_env=HEAVY,
        steps=150_000,
    ),
    Row(
        "residual-deluca-heavy-plain",
        "residual on eq. (13), no deadzone, trained on +30 % mass",
        "deluca",
        (0,),
        action=PLAIN_RESIDUAL,
        train_env=HEAVY,
        steps=150_000,
    ),
    Row(
        "residual-deluca-both",
        "residual on eq. (13), trained on both plants",
        "deluca",
        (0,),
        action=RESIDUAL,
        hyperparams=BOTH_PLANTS,
        steps=150_000,
    ),
    Row(
        "kr15-residual-deluca",
        "residual on eq. (13)",
        "deluca",
        (0,),
        env_id=KR15,
        action=RESIDUAL,
        eval_task={},
        plants=("nominal",),
        steps=20_000,
    ),
    Row("pure-sensors-lstm", "pure RL (motor offsets), LSTM", "sensors", (0,), algo="recurrentppo"),
    Row("pure-ekf", "pure RL (motor offsets)", "ekf", (0,), steps=50_000),
)

CLASSICAL = (  # (controller, label, state sources); the EKF's per-arm filter is slow
    (EQ13, "eq. (13)", ("true", "deluca", "ekf")),
    ("integral-state-feedback", "eq. (13) + integral action", ("true", "deluca")),
    ("motor-pd", "motor PD", ("true", "deluca")),
)
KR15_CLASSICAL = ((EQ13, "eq. (13)", ("deluca",)),)


def log(message: str, start: float) -> None:
    print(f"[{time.perf_counter() - start:7.0f} s] {message}", flush=True)


# ---------------------------------------------------------------- training
def train_all(rows, runs: Path, start: float) -> None:
    """Every row's first seed, then every row's second seed, ...: an interrupted study
    still has every row."""
    order = sorted(
        ((index, row, seed) for row in rows for index, seed in enumerate(row.seeds)),
        key=lambda item: item[0],
    )
    for _, row, seed in order:
        config = row.config(seed, runs)
        if (Path(config.out_dir) / FINISHED).exists():
            continue
        try:
            result = train(config, progress_bar=False, overwrite=True)
        except Exception as exc:  # one failed run must not stop the study
            log(f"FAILED {row.key} seed {seed}: {exc!r}", start)
            continue
        log(
            f"trained {row.key} seed {seed}: {result.policy_steps} policy steps in "
            f"{result.wall_time:.0f} s, eval tracking RMS {result.eval_tracking_rms:.2e}",
            start,
        )


# ---------------------------------------------------------------- evaluation
def classical_key(controller: str, source: str, options: dict | None = None) -> str:
    """The row key of a classical controller (with non-default ``options``) on a source."""
    variant = "".join(f"+{name}={value}" for name, value in (options or {}).items())
    return f"{controller}{variant}-{source}"


def classical_evaluation(
    env_id: str,
    controller: str,
    source: str,
    env_kwargs: dict,
    episodes: int = EVAL_EPISODES,
    seed: int = EVAL_SEED,
    options: dict | None = None,
) -> Evaluation:
    """A classical controller (with ``options``) on the evaluation episodes, through the
    policy stack: a residual on it whose action is zero applies exactly its torque."""
    action = {"kind": "residual", "residual": controller, "residual_options": options or {}}
    spec = PolicySpec(
        env_id=env_id, state=source, env_kwargs=env_kwargs, decimation=10, action=action
    )
    envs = build_policy_env(spec, spec.make_env(episodes, autoreset_mode=AutoresetMode.NEXT_STEP))
    try:
        return evaluate_arms(envs, lambda obs: np.zeros((len(obs), envs.n)), seed)
    finally:
        envs.close()


def zero_action_evaluation(
    env_id: str, env_kwargs: dict, episodes: int = EVAL_EPISODES, seed: int = EVAL_SEED
) -> Evaluation:
    """The motor-offset PD with a zero action: where a pure-RL policy starts."""
    spec = PolicySpec(
        env_id=env_id,
        state="true",
        env_kwargs=env_kwargs,
        decimation=10,
        action={"kind": "motor-offset"},
    )
    envs = build_policy_env(spec, spec.make_env(episodes, autoreset_mode=AutoresetMode.NEXT_STEP))
    try:
        return evaluate_arms(envs, lambda obs: np.zeros((len(obs), envs.n)), seed)
    finally:
        envs.close()


EVAL_COLUMNS = (
    "row",
    "label",
    "env",
    "state",
    "algo",
    "seed",
    "plant",
    "episode_seed",
    "tracking_rms",
    "return",
    "saturated",
    "policy_steps",
    "wall_time",
)


def _cached(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with open(path) as handle:
        return list(csv.DictReader(handle))


def _summary(row, seed: int, runs: Path) -> dict | None:
    """The ``summary.json`` of a finished run of ``row``, or None."""
    finished = Path(row.config(seed, runs).out_dir) / FINISHED
    return json.loads(finished.read_text()) if finished.exists() else None


def _stale(records: list[dict], rows, runs: Path) -> set[tuple[str, str]]:
    """(row, seed) of the cached evaluations of a run that was trained again since (its
    summary's policy steps or wall time differ from the evaluated run's)."""
    stale = set()
    for row in rows:
        for seed in row.seeds:
            summary = _summary(row, seed, runs)
            if summary is None:
                continue
            now = (str(summary["policy_steps"]), str(summary["wall_time"]))
            mine = [r for r in records if r["row"] == row.key and r["seed"] == str(seed)]
            if any((r["policy_steps"], r["wall_time"]) != now for r in mine):
                stale.add((row.key, str(seed)))
    return stale


def evaluate_all(study: Study, rows, runs: Path, out: Path, start: float) -> list[dict]:
    """Every run of ``rows`` and every classical controller of ``study`` x plant x episode
    -> evaluations.csv (cached: what it holds is not evaluated again, unless the run was
    trained again since)."""
    path = out / "evaluations.csv"
    cached = _cached(path)
    stale = _stale(cached, rows, runs)
    records = [r for r in cached if (r["row"], r["seed"]) not in stale]
    done = {(r["row"], r["seed"], r["plant"]) for r in records}
    episodes, first = study.eval_episodes, study.eval_seed

    def add(key, label, env_id, state, algo, seed, plant, evaluation, steps="", wall=""):
        for episode, rms, ret, sat in zip(
            evaluation.seeds,
            evaluation.tracking_rms,
            evaluation.returns,
            evaluation.saturated_actions,
            strict=True,
        ):
            records.append(
                dict(
                    row=key,
                    label=label,
                    env=env_id.split("/")[-1],
                    state=state,
                    algo=algo,
                    seed=str(seed),
                    plant=plant,
                    episode_seed=episode,
                    tracking_rms=rms,
                    **{"return": ret},
                    saturated=sat,
                    policy_steps=steps,
                    wall_time=wall,
                )
            )
        save()  # after every evaluation: an interrupted study keeps what it evaluated

    def save() -> None:
        out.mkdir(parents=True, exist_ok=True)
        with open(path, "w", newline="") as handle:
            writer = csv.DictWriter(handle, EVAL_COLUMNS)
            writer.writeheader()
            writer.writerows(records)

    def missing(key, seed, plant) -> bool:
        return (key, str(seed), plant) not in done

    for env_id, table in ((TWO_LINK, study.classical), (KR15, study.kr15_classical)):
        if not any(row.env_id == env_id for row in rows):
            continue
        task = study.task if env_id == TWO_LINK else {}
        names = dict.fromkeys(name for row in rows if row.env_id == env_id for name in row.plants)
        plants = {name: study.plants[name] for name in names}
        for controller, label, sources, *options in table:
            for source in sources:
                key = classical_key(controller, source, *options)
                key += "-kr15" if env_id == KR15 else ""
                for plant, kwargs in plants.items():
                    if missing(key, "", plant):
                        env_kwargs = {**task, **kwargs}
                        evaluation = classical_evaluation(
                            env_id, controller, source, env_kwargs, episodes, first, *options
                        )
                        add(key, label, env_id, source, "", "", plant, evaluation)
                        log(f"evaluated {key} on {plant}: {evaluation.rms:.2e}", start)
        key = "zero-offset" + ("-kr15" if env_id == KR15 else "")
        for plant, kwargs in plants.items() if study.zero_offset else ():
            if missing(key, "", plant):
                add(
                    key,
                    "motor-offset PD, zero action (pure RL's start)",
                    env_id,
                    "true",
                    "",
                    "",
                    plant,
                    zero_action_evaluation(env_id, {**task, **kwargs}, episodes, first),
                )
    for row in rows:
        for seed in row.seeds:
            summary = _summary(row, seed, runs)
            if summary is None:
                continue
            run = None
            for plant in row.plants:
                if missing(row.key, seed, plant):
                    run = run or load_run(row.config(seed, runs).out_dir, trust_pickle=True)
                    kwargs = {**row.eval_task, **study.plants[plant]}
                    evaluation = evaluate_run(run, episodes, first, kwargs)
                    add(
                        row.key,
                        row.label,
                        row.env_id,
                        row.state,
                        row.algo,
                        seed,
                        plant,
                        evaluation,
                        summary["policy_steps"],
                        summary["wall_time"],
                    )
                    log(f"evaluated {row.key} seed {seed} on {plant}: {evaluation.rms:.2e}", start)
    save()
    return records


# ---------------------------------------------------------------- report
def _rms(records) -> float:
    return float(np.sqrt(np.mean([float(r["tracking_rms"]) ** 2 for r in records])))


TABLE_COLUMNS = (
    "env",
    "policy / controller",
    "state",
    "training seeds",
    "track RMS nominal [rad]",
    "range nominal",
    "track RMS +30 % mass [rad]",
    "range +30 % mass",
    "policy steps",
    "training time [s]",
)


def table(records: list[dict]) -> list[dict]:
    """One line per row key: per training seed the RMS over the episodes; the mean over
    seeds and their range."""
    order = list(dict.fromkeys(r["row"] for r in records))
    lines = []
    for key in order:
        mine = [r for r in records if r["row"] == key]
        first = mine[0]
        seeds = sorted({r["seed"] for r in mine})
        line = {
            "env": first["env"],
            "policy / controller": first["label"]
            + (f" ({first['algo']})" if first["algo"] not in ("", "ppo") else ""),
            "state": first["state"],
            "training seeds": len(seeds) if seeds != [""] else "—",
        }
        for plant, suffix in (("nominal", "nominal"), ("mass+30%", "+30 % mass")):
            per_seed = seed_rms(mine, key, plant)
            name = "track RMS nominal [rad]" if plant == "nominal" else "track RMS +30 % mass [rad]"
            line[name] = f"{np.mean(per_seed):.2e}" if per_seed else ""
            line[f"range {suffix}"] = (
                f"{min(per_seed):.1e} – {max(per_seed):.1e}" if len(per_seed) > 1 else ""
            )
        steps = [float(r["policy_steps"]) for r in mine if r["policy_steps"] not in ("", None)]
        walls = [float(r["wall_time"]) for r in mine if r["wall_time"] not in ("", None)]
        line["policy steps"] = f"{np.mean(steps):.0f}" if steps else ""
        line["training time [s]"] = f"{np.mean(walls):.0f}" if walls else ""
        lines.append(line)
    return lines


def write_table(lines: list[dict], out: Path) -> None:
    with open(out / "table.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, TABLE_COLUMNS)
        writer.writeheader()
        writer.writerows(lines)
    numeric = {
        "training seeds",
        "track RMS nominal [rad]",
        "range nominal",
        "track RMS +30 % mass [rad]",
        "range +30 % mass",
        "policy steps",
        "training time [s]",
    }
    text = [
        "| " + " | ".join(TABLE_COLUMNS) + " |",
        "|" + "|".join("---:" if c in numeric else "---" for c in TABLE_COLUMNS) + "|",
    ]
    text += ["| " + " | ".join(str(line[c]) for c in TABLE_COLUMNS) + " |" for line in lines]
    (out / "table.md").write_text("\n".join(text) + "\n")


def seed_rms(records, key: str, plant: str) -> list[float]:
    """A row's RMS over the evaluation episodes on a plant, one per training seed (in
    seed order; one for a classical row)."""
    mine = [r for r in records if r["row"] == key and r["plant"] == plant]
    seeds = sorted({r["seed"] for r in mine})
    return [_rms([r for r in mine if r["seed"] == s]) for s in seeds]


def row_rms(records, key: str, plant: str) -> float:
    """A row's RMS on a plant: the mean over its training seeds of each seed's RMS over
    the evaluation episodes (NaN when the row was not evaluated)."""
    per_seed = seed_rms(records, key, plant)
    return float(np.mean(per_seed)) if per_seed else float("nan")


@dataclass(frozen=True)
class Target:
    """A target of a study: ``measured`` against ``bound`` (``rule`` says where the bound
    comes from); met when measured <= bound, or measured < bound if ``strict``."""

    name: str
    measured: float
    bound: float
    rule: str
    strict: bool = False
    unit: str = "rad"

    @property
    def verdict(self) -> str:
        """ "met", "missed", or "—" when a number is missing (a row not evaluated)."""
        ratio = self.measured / self.bound
        if not np.isfinite(ratio):
            return "—"
        return "met" if (ratio < 1 if self.strict else ratio <= 1) else "missed"

    def line(self) -> dict:
        """The target as a line of ``targets.md`` ("—" for a number not measured)."""

        def number(value: float, text: str) -> str:
            return text if np.isfinite(value) else "—"

        ratio = self.measured / self.bound
        comparison = "<" if self.strict else "≤"
        return {
            "target": self.name,
            "measured": number(self.measured, f"{self.measured:.2e} {self.unit}"),
            "bound": f"{comparison} "
            + number(self.bound, f"{self.bound:.2e} {self.unit}")
            + f" ({self.rule})",
            "measured / bound": number(ratio, f"{ratio:.3f}"),
            "verdict": self.verdict,
        }


def targets(records: list[dict]) -> list[dict]:
    """The targets of the study, each with the measured value, its bound and the verdict
    (``measured / bound``: met when <= 1)."""

    def rms(key, plant="nominal"):
        return row_rms(records, key, plant)

    half_eq13 = min(0.5 * rms(f"{EQ13}-deluca", "mass+30%"), 4e-3)
    half_rule = "min(0.5 x eq. (13) on De Luca, 4e-3 rad)"
    integral = rms("integral-state-feedback-deluca", "mass+30%")
    integral_rule = "eq. (13) + integral action on De Luca"
    no_harm = 1.2 * rms(f"{EQ13}-deluca")
    no_harm_rule = "1.2 x eq. (13) on De Luca"
    checks = [
        ("pure RL, true state, nominal", rms("pure-true"), 1e-3, "1e-3 rad"),
        (
            "pure RL, De Luca estimate, nominal",
            rms("pure-deluca"),
            1.5 * rms("pure-true"),
            "1.5 x pure RL on the true state",
        ),
        (
            "pure RL, raw sensors (4 stacked frames), nominal",
            rms("pure-sensors"),
            3 * rms("pure-true"),
            "3 x pure RL on the true state",
        ),
        (
            "pure RL, raw sensors (RecurrentPPO), nominal",
            rms("pure-sensors-lstm"),
            3 * rms("pure-true"),
            "3 x pure RL on the true state",
        ),
        ("residual on eq. (13), De Luca, nominal", rms("residual-deluca"), no_harm, no_harm_rule),
        (
            "residual on eq. (13), De Luca, +30 % mass (trained there)",
            rms("residual-deluca-heavy", "mass+30%"),
            half_eq13,
            half_rule,
        ),
        (
            "residual on eq. (13), De Luca, +30 % mass (trained there), vs integral action",
            rms("residual-deluca-heavy", "mass+30%"),
            integral,
            integral_rule,
        ),
        (
            "residual on eq. (13) without deadzone, De Luca, nominal",
            rms("residual-deluca-plain"),
            no_harm,
            no_harm_rule,
        ),
        (
            "residual on eq. (13) without deadzone, De Luca, +30 % mass (trained there)",
            rms("residual-deluca-heavy-plain", "mass+30%"),
            half_eq13,
            half_rule,
        ),
        (
            "residual on eq. (13) without deadzone, De Luca, +30 % mass (trained there), vs "
            "integral action",
            rms("residual-deluca-heavy-plain", "mass+30%"),
            integral,
            integral_rule,
        ),
        (
            "residual on eq. (13) trained on both plants, De Luca, nominal",
            rms("residual-deluca-both"),
            no_harm,
            no_harm_rule,
        ),
        (
            "residual on eq. (13) trained on both plants, De Luca, +30 % mass",
            rms("residual-deluca-both", "mass+30%"),
            half_eq13,
            half_rule,
        ),
        (
            "residual on eq. (13) trained on both plants, De Luca, +30 % mass, vs integral action",
            rms("residual-deluca-both", "mass+30%"),
            integral,
            integral_rule,
        ),
    ]
    return [Target(*check).line() for check in checks]


def write_targets(lines: list[dict], out: Path) -> None:
    columns = list(lines[0])
    text = ["| " + " | ".join(columns) + " |", "|" + "|".join("---" for _ in columns) + "|"]
    text += ["| " + " | ".join(line[c] for c in columns) + " |" for line in lines]
    (out / "targets.md").write_text("\n".join(text) + "\n")


def gather_curves(rows, runs: Path, out: Path) -> list[dict]:
    """The learning curves of the finished runs of ``rows`` -> ``curves.csv``; a run whose
    folder is not under ``runs`` keeps its curve of the earlier ``curves.csv``."""
    earlier: dict[tuple[str, str], list[dict]] = {}
    if (out / "curves.csv").exists():
        with open(out / "curves.csv") as handle:
            for record in csv.DictReader(handle):
                earlier.setdefault((record["row"], record["seed"]), []).append(record)
    records = []
    for row in rows:
        for seed in row.seeds:
            path = Path(row.config(seed, runs).out_dir) / CURVE_FILE
            if not (path.parent / FINISHED).exists():
                records += earlier.get((row.key, str(seed)), [])
                continue
            with open(path) as handle:
                for record in csv.DictReader(handle):
                    records.append({"row": row.key, "seed": str(seed), **record})
    if records:
        with open(out / "curves.csv", "w", newline="") as handle:
            writer = csv.DictWriter(handle, list(records[0]))
            writer.writeheader()
            writer.writerows(records)
    return records


def plot_curves(records: list[dict], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(12, 8), sharey="row")
    keys = list(dict.fromkeys(r["row"] for r in records))
    tab20 = plt.get_cmap("tab20")  # 10 dark colours, then their 10 light twins
    colors = [tab20(i) for i in (*range(0, 20, 2), *range(1, 20, 2))]
    for index, key in enumerate(keys):
        mine = [r for r in records if r["row"] == key]
        seeds = sorted({r["seed"] for r in mine})
        per_seed = [[r for r in mine if r["seed"] == s] for s in seeds]
        length = min(len(c) for c in per_seed)
        steps = np.array([float(r["policy_steps"]) for r in per_seed[0][:length]])
        wall = np.mean([[float(r["wall_time"]) for r in c[:length]] for c in per_seed], axis=0)
        label = f"{key} ({len(seeds)} seed{'s' if len(seeds) > 1 else ''})"
        for row_index, column in enumerate(("tracking_rms", "eval_return")):
            values = np.array([[float(r[column]) for r in c[:length]] for c in per_seed])
            for col_index, x in enumerate((steps, wall / 60.0)):
                ax = axes[row_index, col_index]
                (line,) = ax.plot(
                    x, values.mean(axis=0), label=label, color=colors[index % len(colors)]
                )
                if len(seeds) > 1:
                    ax.fill_between(
                        x, values.min(axis=0), values.max(axis=0), alpha=0.2, color=line.get_color()
                    )
    for ax in axes[0]:
        ax.set_yscale("log")
    axes[0, 0].set_ylabel("tracking RMS [rad] (5 evaluation episodes)")
    axes[1, 0].set_ylabel("evaluation return")
    axes[1, 0].set_xlabel("policy steps")
    axes[1, 1].set_xlabel("training wall time [min] (mean over seeds; evaluations excluded)")
    for ax in axes.flat:
        ax.grid(True, which="both", alpha=0.3)
    axes[0, 1].legend(fontsize=7, loc="upper right")
    fig.suptitle("Learning curves: mean and min–max over training seeds")
    fig.tight_layout()
    fig.savefig(out / "learning_curves.png", dpi=110)
    plt.close(fig)


def forget_evaluations(path: Path, keys: set[str]) -> None:
    """Remove the evaluations of these rows from ``evaluations.csv`` (the others stay)."""
    if not path.exists():
        return
    with open(path) as handle:
        kept = [record for record in csv.DictReader(handle) if record["row"] not in keys]
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, EVAL_COLUMNS)
        writer.writeheader()
        writer.writerows(kept)


def report(records: list[dict], out: Path, rows, runs: Path) -> list[str]:
    """The RL study's tables: ``table.md`` / ``table.csv`` and ``targets.md``."""
    write_table(table(records), out)
    write_targets(targets(records), out)
    return ["table.md", "table.csv", "targets.md"]


@dataclass(frozen=True)
class Study:
    """What a study trains, evaluates and reports (this script's, or a sibling's).

    ``rows``: objects with ``key``, ``label``, ``state``, ``algo``, ``env_id``, ``seeds``,
    ``plants`` (names of ``plants``), ``eval_task``, ``steps`` (None: the row's own) and
    ``config(seed, runs) -> TrainConfig`` (`Row`); ``plants``: name -> env kwargs
    of an evaluation plant; ``classical``: (controller, label, state sources[, options])
    evaluated on TwoLinkElastic's ``task`` (``kr15_classical`` on KR15, its default task;
    a row's policies on the row's ``eval_task``); ``zero_offset``: also the
    motor-offset PD with a zero action; ``report(records, out, rows, runs)`` writes the
    study's tables and returns their file names; ``command(row, seed, runs)``: the
    ``elastic-gym train`` command of a run (None: the study has none)."""

    name: str
    description: str
    rows: tuple
    plants: dict[str, dict]
    classical: tuple
    report: Callable[[list[dict], Path, tuple, Path], list[str]]
    runs: str
    out: str
    kr15_classical: tuple = ()
    zero_offset: bool = True
    eval_episodes: int = EVAL_EPISODES
    eval_seed: int = EVAL_SEED
    command: Callable[[object, int, Path], str] | None = None
    task: dict = field(default_factory=lambda: TASK)


RL_STUDY = Study(
    "RL study",
    __doc__.split("\n\n")[0],
    ROWS,
    PLANTS,
    CLASSICAL,
    report,
    "runs/rl_study",
    "docs/results/rl_study",
    kr15_classical=KR15_CLASSICAL,
)


def _choose(parser, kind: str, chosen, valid) -> list:
    unknown = [name for name in chosen or () if name not in valid]
    if unknown:
        parser.error(f"--{kind}: unknown {kind} {unknown}; valid: {list(valid)}")
    return list(valid) if chosen is None else [name for name in valid if name in chosen]


def run(study: Study, argv: list[str] | None = None) -> None:
    """The command line of a study: train what is missing, evaluate, report."""
    parser = argparse.ArgumentParser(description=study.description)
    parser.add_argument("--runs", default=study.runs, help="training run folders")
    parser.add_argument("--out", default=study.out, help="tables and figures")
    keys = [row.key for row in study.rows]
    parser.add_argument(
        "--rows",
        nargs="+",
        metavar="KEY",
        help=f"only these rows (default: all: {keys})".replace("%", "%%"),
    )
    parser.add_argument(
        "--plants",
        nargs="+",
        metavar="NAME",
        help=f"only these evaluation plants (default: all: {list(study.plants)})".replace(
            "%", "%%"
        ),
    )
    parser.add_argument(
        "--episodes",
        type=int,
        default=study.eval_episodes,
        metavar="N",
        help="evaluation episodes per plant (default: %(default)s)",
    )
    parser.add_argument(
        "--report",
        action="store_true",
        help="no training: evaluate finished runs, write tables and figures",
    )
    parser.add_argument(
        "--steps",
        type=int,
        metavar="N",
        help="policy steps of every run instead of the rows' (a smoke test)",
    )
    parser.add_argument(
        "--fresh",
        action="store_true",
        help="remove earlier runs and evaluations of the chosen rows first",
    )
    if study.command is not None:
        parser.add_argument(
            "--commands",
            action="store_true",
            help="print the elastic-gym train command of every run and exit",
        )
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes: must be >= 1, got {args.episodes}")
    chosen = set(_choose(parser, "rows", args.rows, keys))
    plants = _choose(parser, "plants", args.plants, study.plants)
    rows = [
        dataclasses.replace(
            row,
            plants=tuple(p for p in row.plants if p in plants),
            **({} if args.steps is None else {"steps": args.steps}),
        )
        for row in study.rows
        if row.key in chosen
    ]
    study = dataclasses.replace(study, eval_episodes=args.episodes)
    runs, out = Path(args.runs), Path(args.out)
    if getattr(args, "commands", False):
        for row in rows:
            for seed in row.seeds:
                print(study.command(row, seed, runs))
        return
    if args.fresh:
        for row in rows:
            shutil.rmtree(runs / row.key, ignore_errors=True)
        forget_evaluations(out / "evaluations.csv", {row.key for row in rows})
    start = time.perf_counter()
    log(
        f"{study.name}: {sum(len(r.seeds) for r in rows)} training runs of {len(rows)} rows "
        f"into {runs}, report into {out}",
        start,
    )
    if not args.report:
        train_all(rows, runs, start)
    out.mkdir(parents=True, exist_ok=True)
    records = evaluate_all(study, rows, runs, out, start)
    written = study.report(records, out, tuple(rows), runs)
    curves = gather_curves(rows, runs, out)
    if curves:
        plot_curves(curves, out)
        written += ["curves.csv", "learning_curves.png"]
    log(f"wrote {out}/: {', '.join(['evaluations.csv', *written])}", start)


if __name__ == "__main__":
    run(RL_STUDY)
