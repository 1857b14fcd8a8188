"""A fit's result as the identified model file (`elastic_gym.model.identified`)."""

from __future__ import annotations

import datetime

import numpy as np

import elastic_gym
from elastic_gym.identification.fit import FitResult
from elastic_gym.identification.problem import SamplingModel
from elastic_gym.model.identified import (
    AccelerometerBias,
    BaseParameter,
    FitSummary,
    IdentifiedModel,
    JointEstimates,
)

# model file field -> the fit's parameter group
JOINT_FIELDS = {
    "stiffness": "stiffness",
    "damping": "damping",
    "motor_inertia": "motor_inertia",
    "link_mass_scale": "link_mass",
    "viscous_friction": "viscous",
    "coulomb_friction": "coulomb",
}


def _number(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def identified_model(
    result: FitResult,
    log_name: str = "",
    log_sha256: str = "",
    date: str | None = None,
    sampling: SamplingModel | None = None,
) -> IdentifiedModel:
    """The model file of ``result`` (held parameters keep their nominal value and have no
    standard error; ``sampling``: what the fit modelled of the log's sampling)."""
    sampling = sampling or SamplingModel()
    model = result.problem.model
    spec = model.spec
    index = {name: i for i, name in enumerate(result.names)}

    def estimate(group: str, joint: str) -> dict:
        i = index[f"{group}[{joint}]"]
        return {
            "value": float(result.values[i]),
            "std": _number(result.standard_errors[i]),
            "nominal": float(result.nominal[i]),
            "held": result.names[i] in result.held,
        }

    joints = [
        JointEstimates(
            name=joint,
            **{field: estimate(group, joint) for field, group in JOINT_FIELDS.items()},
        )
        for joint in spec.joint_names
    ]
    sensors = [m.name for m in model.accelerometers]
    accelerometers = []
    for name in sensors:
        rows = [index[f"bias[{name}_{axis}]"] for axis in "xyz"]
        accelerometers.append(
            AccelerometerBias(
                name=name,
                bias=tuple(float(result.values[i]) for i in rows),
                std=tuple(float(result.standard_errors[i]) for i in rows),
            )
        )
    base = []
    if result.base is not None:
        b = result.base
        base = [
            BaseParameter(name=name, value=float(v), std=_number(s), nominal=float(nom))
            for name, v, s, nom in zip(b.names, b.values, b.standard_errors, b.nominal, strict=True)
        ]
    axes = [f"{name}_{axis}" for name in sensors for axis in "xyz"]
    grid = result.problem.measurements.grid
    summary = FitSummary(
        log=log_name,
        log_sha256=log_sha256,
        samples=grid.n_samples,
        duration=float((grid.n_samples - 1) * grid.dt),
        torque_hold=sampling.torque_hold,
        delay=sampling.delay,
        accelerometer_cutoff_hz=sampling.accelerometer_cutoff_hz,
        pass_hz=result.band.pass_hz,
        stop_hz=result.band.stop_hz,
        condition_number=_number(result.condition_number),
        residual_std_readings=dict(zip(axes, map(float, result.sigma_readings), strict=True)),
        residual_std_link=dict(zip(spec.joint_names, map(float, result.sigma_link), strict=True)),
        holdout_fit_readings=dict(
            zip(axes, map(float, result.holdout["readings_fit"]), strict=True)
        ),
        holdout_fit_link=dict(
            zip(spec.joint_names, map(float, result.holdout["link_fit"]), strict=True)
        ),
        warnings=list(result.warnings),
        version=elastic_gym.__version__,
        date=date or datetime.date.today().isoformat(),
    )
    return IdentifiedModel(
        robot=spec.name,
        coulomb_velocity=result.problem.coulomb_velocity,
        joints=joints,
        accelerometers=accelerometers,
        base_parameters=base,
        fit=summary,
    )
