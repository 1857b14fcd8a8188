"""Did the log excite what the fit estimates? Checks that name what it did not.

* The torsion band: K and D show in the accelerometers only through the joints'
  deflection dynamics, whose modes are the arm's elastic natural frequencies
  (`RobotModel.natural_frequencies` at the log's median motor configuration). If the
  accelerometers' power spectral density in [0.7 f_min, 1.3 f_max] (the modes below the
  filter's pass band) is not `MIN_TORSION_SNR` times their noise floor (between 0.3 and
  0.45 of the sampling rate), no joint's K, D is identifiable from the log.
* The standard errors: a parameter whose relative standard error exceeds its threshold
  (`Thresholds`) is named as poorly identified; K, D or B at the fit's bound, or with a
  standard error `HOLD_FACTOR` times the threshold, are held at nominal (a linear
  parameter never is: its estimate stays unbiased, only less precise).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from elastic_gym.model import RobotModel

MIN_TORSION_SNR = 30.0
HOLD_FACTOR = 10.0


@dataclass(frozen=True)
class Thresholds:
    """Largest relative standard errors of an identified parameter (friction: of the
    joint's RMS joint torque, per unit of friction torque; biases: m/s^2)."""

    stiffness: float = 0.005
    damping: float = 0.05
    motor_inertia: float = 0.01
    link_mass: float = 0.01
    friction: float = 0.01
    bias: float = 0.005

    def of(self, name: str) -> float:
        group = name.partition("[")[0]
        return getattr(self, "friction" if group in ("viscous", "coulomb") else group)


@dataclass(frozen=True)
class TorsionBand:
    """The band of the torsion modes and how far above the noise the log is there."""

    low_hz: float
    high_hz: float
    modes_hz: tuple[float, ...]
    snr: float

    @property
    def excited(self) -> bool:
        return self.snr >= MIN_TORSION_SNR

    def warning(self) -> str:
        modes = ", ".join(f"{f:.1f}" for f in self.modes_hz)
        return (
            f"the log does not excite the joint torsion: between {self.low_hz:.1f} and "
            f"{self.high_hz:.1f} Hz, where the torsion modes are ({modes} Hz), the "
            f"accelerometers read {self.snr:.3g} times their noise floor (at least "
            f"{MIN_TORSION_SNR:g} needed); stiffness and damping are not identifiable from "
            "it and are held at their nominal values. Record with a torque or reference "
            "dither across these frequencies (e.g. 2-25 Hz)."
        )


def torsion_band(
    acceleration: np.ndarray,
    motor_position: np.ndarray,
    dt: float,
    model: RobotModel,
    pass_hz: float,
) -> TorsionBand:
    """The `TorsionBand` of a log (module docstring)."""
    from scipy.signal import welch  # imported here: scipy.signal costs a second to import

    fs = 1.0 / dt
    free, _ = model.natural_frequencies(np.median(motor_position, axis=0))
    modes = np.sort(free) / (2.0 * np.pi)
    inside = modes[modes <= pass_hz]
    if not len(inside):
        inside = modes[:1]
    low, high = 0.7 * inside[0], min(1.3 * inside[-1], pass_hz, 0.3 * fs)
    y = acceleration - acceleration.mean(axis=0)
    f, psd = welch(y, fs=fs, nperseg=min(len(y), round(fs)), axis=0)
    total = psd.sum(axis=1)
    floor = float(np.median(total[(f > 0.3 * fs) & (f < 0.45 * fs)]))
    band = (f >= low) & (f <= high)
    snr = float(np.mean(total[band]) / floor) if floor > 0 and band.any() else float("inf")
    return TorsionBand(float(low), float(high), tuple(float(m) for m in modes), snr)


def poorly_excited(
    names: list[str],
    values: np.ndarray,
    standard_errors: np.ndarray,
    torque_scale: np.ndarray,
    velocity_scale: np.ndarray,
    joint_names: tuple[str, ...],
    at_bound: set[str],
    thresholds: Thresholds,
) -> dict[str, tuple[str, bool]]:
    """name -> (why, whether to hold it), for the parameters the log did not identify to
    their threshold (module docstring).

    ``torque_scale``, ``velocity_scale``: per joint, the RMS joint torque and link
    velocity (friction's standard errors are judged against the torque they make)."""
    out: dict[str, tuple[str, bool]] = {}
    for name, value, se in zip(names, values, standard_errors, strict=True):
        group = name.partition("[")[0]
        if name in at_bound:
            out[name] = ("ended at the fit's bound", True)
            continue
        if not np.isfinite(se):
            continue
        limit = thresholds.of(name)
        if group in ("viscous", "coulomb"):
            j = joint_names.index(name[len(group) + 1 : -1])
            per_unit = velocity_scale[j] if group == "viscous" else 1.0
            relative = se * per_unit / max(torque_scale[j], 1e-12)
            if relative > limit:
                why = (
                    f"standard error {se:.3g} is {100 * relative:.2g} % of the joint's RMS "
                    f"torque (more than {100 * limit:g} %)"
                )
                out[name] = (why, False)
        elif group == "bias":
            if se > limit:
                out[name] = (f"standard error {se:.3g} m/s^2 (more than {limit:g})", False)
        elif abs(value) > 0 and se / abs(value) > limit:
            relative = se / abs(value)
            why = f"relative standard error {100 * relative:.2g} % (more than {100 * limit:g} %)"
            out[name] = (why, relative > HOLD_FACTOR * limit)
    return out
