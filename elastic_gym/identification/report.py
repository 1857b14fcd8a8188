"""The identification report: a markdown page and a figure of the held-out part.

The figure shows, over the held-out part of the log (the samples the fit did not see),
each accelerometer axis as measured (through the fit's zero-phase filter) and as the
identified model predicts it from the motor encoders and torques, and each joint's
torque tau_J as the motor side gives it (tau - B theta'') and as the identified link side
predicts it (M q'' + C q' + g + d). Uses matplotlib's Agg canvas through
``matplotlib.figure.Figure`` (no pyplot, no display).
"""

from __future__ import annotations

import io

import numpy as np
from matplotlib.figure import Figure

from elastic_gym.identification.fit import FitResult
from elastic_gym.model.identified import IdentifiedModel

FIGURE_NAME = "identification.png"
JOINT_ROWS = (
    ("stiffness", "K", "N m/rad"),
    ("damping", "D", "N m s/rad"),
    ("motor_inertia", "B", "kg m²"),
    ("link_mass_scale", "link mass scale", "-"),
    ("viscous_friction", "viscous friction", "N m s/rad"),
    ("coulomb_friction", "Coulomb friction", "N m"),
)


def figure_png(result: FitResult, max_seconds: float = 5.0) -> bytes:
    """PNG of measured against predicted signals on (at most ``max_seconds`` of) the
    held-out part."""
    rows = result.holdout_rows
    if not len(rows):
        rows = result.rows
    t = result.time[rows]
    keep = t <= t[0] + max_seconds
    rows, t = rows[keep], t[keep]
    problem, terms = result.problem, result.terms
    measured = problem.measurements.acceleration[rows]
    predicted = terms.predicted[rows] + result.bias
    link_measured = terms.rhs[rows]
    link_predicted = terms.columns[rows] @ result.link
    sensors = [m.name for m in problem.model.accelerometers]
    joints = problem.model.spec.joint_names
    panels = len(sensors) + len(joints)
    figure = Figure(figsize=(10, 2.2 * panels), constrained_layout=True)
    axes = figure.subplots(panels, 1, sharex=True, squeeze=False)[:, 0]
    colours = ("tab:blue", "tab:orange", "tab:green")
    for s, name in enumerate(sensors):
        ax = axes[s]
        for a, axis in enumerate("xyz"):
            c = 3 * s + a
            ax.plot(t, measured[:, c], color=colours[a], lw=1.2, label=f"{axis} measured")
            ax.plot(t, predicted[:, c], color="k", lw=0.8, ls="--", label=f"{axis} predicted")
        ax.set_ylabel(f"{name}\n(m/s²)")
        ax.legend(loc="upper right", ncol=3, fontsize=7)
    for j, joint in enumerate(joints):
        ax = axes[len(sensors) + j]
        ax.plot(t, link_measured[:, j], color="tab:red", lw=1.2, label="motor side τ - Bθ''")
        ax.plot(t, link_predicted[:, j], color="k", lw=0.8, ls="--", label="link side (model)")
        ax.set_ylabel(f"τ_J {joint}\n(N m)")
        ax.legend(loc="upper right", ncol=2, fontsize=7)
    axes[-1].set_xlabel("time (s)")
    figure.suptitle("held-out part of the log: measured and predicted by the identified model")
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=90)
    return buffer.getvalue()


def _fmt(x: float | None, digits: int = 5) -> str:
    return "—" if x is None else f"{x:.{digits}g}"


def report_markdown(result: FitResult, model_file: IdentifiedModel, title: str) -> str:
    """The report page (markdown) of an identification."""
    fit = model_file.fit
    grid_hz = 1.0 / (result.decimation * result.problem.measurements.grid.dt)
    lines = [
        f"# Identification of {title}",
        "",
        f"Robot `{model_file.robot}`; log `{fit.log}` ({fit.samples} samples, "
        f"{fit.duration:.3g} s); elastic-gym {fit.version}, {fit.date}.",
        "",
    ]
    if fit.warnings:
        lines += ["## Warnings", ""] + [f"- {w}" for w in fit.warnings] + [""]
    lines += [
        "## Joints",
        "",
        "Identified values with their standard errors; held: not identifiable from this log "
        "(kept at the nominal value).",
        "",
    ]
    header = "| parameter | unit | " + " | ".join(j.name for j in model_file.joints) + " |"
    lines += [header, "|---|---|" + "---|" * len(model_file.joints)]
    for field, label, unit in JOINT_ROWS:
        cells = []
        for joint in model_file.joints:
            e = getattr(joint, field)
            if e.held:
                cells.append(f"{_fmt(e.value)} (held)")
                continue
            std = f" ± {_fmt(e.std, 2)}" if e.std is not None else ""
            change = ""
            if e.nominal:
                change = f" ({100.0 * (e.value / e.nominal - 1.0):+.2f} %)"
            cells.append(f"{_fmt(e.value)}{std}{change}")
        lines.append(f"| {label} | {unit} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "In parentheses: the change from the nominal value. Link mass scale: the mass and "
        "rotational inertia of the link the joint moves, relative to the nominal model.",
        "",
        "## Accelerometer biases (m/s², sensor frame)",
        "",
        "| sensor | x | y | z |",
        "|---|---|---|---|",
    ]
    for acc in model_file.accelerometers:
        stds = acc.std or (None, None, None)
        cells = [f"{b:+.4f} ± {_fmt(s, 2)}" for b, s in zip(acc.bias, stds, strict=True)]
        lines.append(f"| {acc.name} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "## Fit",
        "",
        f"- filter: zero-phase, pass band to {_fmt(fit.pass_hz, 3)} Hz, stop from "
        f"{_fmt(fit.stop_hz, 3)} Hz; residuals on a {grid_hz:.4g} Hz grid",
        f"- condition number of the column-scaled Jacobian: {_fmt(fit.condition_number, 4)}",
        f"- torsion band {result.torsion.low_hz:.1f}–{result.torsion.high_hz:.1f} Hz: "
        f"accelerometers at {result.torsion.snr:.3g} times their noise floor",
        f"- {result.evaluations} residual evaluations, {result.seconds:.2f} s",
        "",
        "Held-out part (the last part of the log, not used by the fit): residual RMS and "
        "fit = 100 (1 - |residual| / |signal - mean|).",
        "",
        "| channel | residual std (fit) | held-out RMS | held-out fit % |",
        "|---|---|---|---|",
    ]
    axes = list(fit.holdout_fit_readings)
    for c, name in enumerate(axes):
        lines.append(
            f"| {name} (m/s²) | {fit.residual_std_readings[name]:.4g} | "
            f"{result.holdout['readings_rms'][c]:.4g} | {fit.holdout_fit_readings[name]:.2f} |"
        )
    for j, name in enumerate(fit.holdout_fit_link):
        lines.append(
            f"| τ_J {name} (N m) | {fit.residual_std_link[name]:.4g} | "
            f"{result.holdout['link_rms'][j]:.4g} | {fit.holdout_fit_link[name]:.2f} |"
        )
    lines += ["", f"![measured and predicted on the held-out part]({FIGURE_NAME})", ""]
    if model_file.base_parameters:
        lines += [
            "## Base inertial parameters",
            "",
            "The combinations of the links' inertial parameters (mass m, first moments "
            "mx, my, mz in kg m, inertias in kg m² about the joint frame) that the link "
            "side identifies, fitted freely (not through the mass scales); the last "
            "column is what the identified mass scales give.",
            "",
            "| base parameter | identified | nominal | from the mass scales |",
            "|---|---|---|---|",
        ]
        scaled = result.base.scaled if result.base is not None else np.zeros(0)
        for p, s in zip(model_file.base_parameters, scaled, strict=False):
            lines.append(
                f"| {p.name} | {p.value:.5g} ± {_fmt(p.std, 2)} | {_fmt(p.nominal)} | {s:.5g} |"
            )
        if result.base is not None:
            lines += [
                "",
                f"Condition number of the base regressor: {result.base.condition_number:.4g}.",
            ]
        lines.append("")
    return "\n".join(lines)
