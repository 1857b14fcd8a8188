"""The identification excitation: Fourier-series references chosen for a well-conditioned
regressor (Swevers, Ganseman, Tükel, De Schutter & Van Brussel 1997; Gautier & Khalil
1992), inside the workspace and the torque limits, plus a torque dither across the
torsion modes.

The link side τ_J = M(q) q'' + C(q, q') q' + g(q) + F_v q' + F_c sign(q') is linear in the
inertial parameters (pinocchio's joint torque regressor, 10 per body) and the friction
coefficients. `design_excitation` picks the coefficients a_l, b_l of q_d = q0 + Σ_l a_l
sin(l ω t) + b_l cos(l ω t) that minimize the condition number of that regressor stacked
over one period, reduced to the identifiable (base) columns and with unit-norm columns:
random starts, then the Nelder–Mead simplex. Each joint's amplitude bound Σ_l |(a_l, b_l)| fills
`fill` of the workspace box's half-width, and the rigid torque along the reference (with
B q_d'') stays within `torque_fill` of the limits. The reference reaches the slow modes;
the dither (`elastic_gym.envs.fourier`) the torsion modes, without which K and D cannot
be told apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.linalg import qr
from scipy.optimize import minimize
from threadpoolctl import threadpool_limits

from elastic_gym.envs.fourier import DitherOptions, fourier_series
from elastic_gym.model import RobotModel

BASE_TOLERANCE = 1e-8  # |R_ii| / |R_00| below it: a column that is not identifiable
FRICTION_VELOCITY = 0.01  # rad/s: tanh smoothing of the Coulomb column
SAMPLES_PER_HARMONIC = 20
PENALTY = 10.0


@dataclass(frozen=True)
class ExcitationDesign:
    """A designed excitation: the `fourier` task's options (`task_options`), the
    condition number of its regressor and that of the best random start, and the largest
    rigid torque along the reference in fractions of the limits."""

    task_options: dict
    condition_number: float
    start_condition_number: float
    torque_ratio: float
    base_columns: int


class RegressorDesign:
    """The regressor of a reference (module docstring) for a model, limits and box."""

    def __init__(
        self,
        model: RobotModel,
        torque_limit: np.ndarray,
        low: np.ndarray,
        high: np.ndarray,
        period: float,
        harmonics: int,
        fill: float,
        offset: np.ndarray | None = None,
    ) -> None:
        self.model, self.n = model, model.n
        self.data = model.pin_model.createData()
        self.limit = np.asarray(torque_limit, dtype=float)
        self.half = 0.5 * (np.asarray(high) - np.asarray(low))
        self.offset = 0.5 * (np.asarray(high) + np.asarray(low)) if offset is None else offset
        self.period, self.harmonics, self.fill = period, harmonics, fill
        samples = SAMPLES_PER_HARMONIC * harmonics
        self.t = np.arange(samples) * period / samples
        self.base: np.ndarray | None = None

    # ------------------------------------------------------------------ coefficients
    def coefficients(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(sine, cosine) (L, n) of the free parameters x, each joint scaled so that
        Σ_l |(a_l, b_l)| = fill · half-width."""
        L, n = self.harmonics, self.n
        sine, cosine = x[: L * n].reshape(L, n), x[L * n :].reshape(L, n)
        bound = np.sqrt(sine**2 + cosine**2).sum(axis=0)
        scale = self.fill * self.half / np.where(bound > 0.0, bound, 1.0)
        return sine * scale, cosine * scale

    def trajectory(self, sine: np.ndarray, cosine: np.ndarray) -> np.ndarray:
        """(q, q', q'') at the samples of one period: (3, S, n)."""
        f = fourier_series(self.t, sine, cosine, self.period, 2)
        q = f[:, 0] + self.offset
        return np.stack([q, f[:, 1], f[:, 2]])

    def regressor(self, motion: np.ndarray) -> np.ndarray:
        """The stacked link-side regressor (S n, 10 bodies + 2 n): inertial parameters,
        viscous and (smoothed) Coulomb friction per joint."""
        q, dq, ddq = motion
        S, n = q.shape
        model, data = self.model.pin_model, self.data
        inertial = 10 * (model.njoints - 1)
        W = np.zeros((S, n, inertial + 2 * n))
        joints = np.arange(n)
        for k in range(S):
            W[k, :, :inertial] = pin.computeJointTorqueRegressor(model, data, q[k], dq[k], ddq[k])
        W[:, joints, inertial + joints] = dq  # viscous friction F_v q'
        W[:, joints, inertial + n + joints] = np.tanh(dq / FRICTION_VELOCITY)  # Coulomb
        return W.reshape(S * n, -1)

    def torque_ratio(self, motion: np.ndarray) -> float:
        """The largest |M q'' + C q' + g + B q''| over the samples, in fractions of the
        torque limits."""
        q, dq, ddq = motion
        tau = np.array([self.model.rnea(q[k], dq[k], ddq[k]) for k in range(len(q))])
        tau = tau + self.model.B * ddq
        return float(np.max(np.abs(tau) / self.limit))

    def find_base(self, rng: np.random.Generator) -> np.ndarray:
        """The identifiable columns: QR with column pivoting of the regressor of a random
        rich reference (identifiability is structural: the same for almost every
        motion)."""
        x = rng.standard_normal(2 * self.harmonics * self.n)
        W = self.regressor(self.trajectory(*self.coefficients(x)))
        _, R, pivots = qr(W, mode="economic", pivoting=True)
        diagonal = np.abs(np.diag(R))
        rank = int(np.sum(diagonal > BASE_TOLERANCE * diagonal[0]))
        self.base = np.sort(pivots[:rank])
        return self.base

    def condition_number(self, motion: np.ndarray) -> float:
        """The condition number of the base regressor with unit-norm columns."""
        assert self.base is not None
        W = self.regressor(motion)[:, self.base]
        norms = np.linalg.norm(W, axis=0)
        singular = np.linalg.svd(W / np.where(norms > 0.0, norms, 1.0), compute_uv=False)
        return float(singular[0] / singular[-1]) if singular[-1] > 0.0 else np.inf

    def objective(self, x: np.ndarray, torque_fill: float) -> float:
        motion = self.trajectory(*self.coefficients(x))
        excess = max(0.0, self.torque_ratio(motion) / torque_fill - 1.0)
        return float(np.log(self.condition_number(motion)) + PENALTY * excess**2)


def design_excitation(
    model: RobotModel,
    torque_limit: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    period: float = 10.0,
    harmonics: int = 5,
    fill: float = 0.6,
    torque_fill: float = 0.5,
    dither: DitherOptions | None = None,
    seed: int = 0,
    starts: int = 16,
    evaluations: int = 400,
    ramp: float = 1.0,
) -> ExcitationDesign:
    """Coefficients of the `fourier` task for `model` (module docstring), reproducible
    from `seed`; `evaluations` bounds the simplex's function evaluations. BLAS runs on one
    thread (small matrices: threads only compete)."""
    with threadpool_limits(limits=1):
        rng = np.random.default_rng(seed)
        design = RegressorDesign(model, torque_limit, low, high, period, harmonics, fill)
        design.find_base(rng)
        x, start_cond = _best_coefficients(design, rng, starts, evaluations, torque_fill)
        sine, cosine, motion, ratio = _within_torque_fill(design, x, torque_fill)
        options = {
            "period": float(period),
            "offset": design.offset.tolist(),
            "sine": sine.tolist(),
            "cosine": cosine.tolist(),
            "ramp": float(ramp),
            **({"dither": dither.model_dump(mode="json")} if dither is not None else {}),
        }
        return ExcitationDesign(
            task_options=options,
            condition_number=design.condition_number(motion),
            start_condition_number=start_cond,
            torque_ratio=ratio,
            base_columns=len(design.base) if design.base is not None else 0,
        )


def _best_coefficients(
    design: RegressorDesign, rng, starts: int, evaluations: int, torque_fill: float
) -> tuple[np.ndarray, float]:
    """The Fourier coefficients minimising the design's objective: the best of ``starts``
    random draws, refined by Nelder-Mead (at most ``evaluations`` evaluations) if that
    improves it; and the condition number of the best draw."""
    size = 2 * design.harmonics * design.n
    candidates = [rng.standard_normal(size) for _ in range(starts)]
    values = [design.objective(x, torque_fill) for x in candidates]
    best = candidates[int(np.argmin(values))]
    start_cond = design.condition_number(design.trajectory(*design.coefficients(best)))
    result = minimize(
        design.objective,
        best,
        args=(torque_fill,),
        method="Nelder-Mead",
        options={"maxfev": evaluations, "xatol": 1e-3, "fatol": 1e-4, "adaptive": True},
    )
    return (result.x if result.fun <= min(values) else best), start_cond


def _within_torque_fill(design: RegressorDesign, x: np.ndarray, torque_fill: float) -> tuple:
    """(sine, cosine, motion, torque ratio) of coefficients ``x`` shrunk until the motion
    needs at most ``torque_fill`` of the torque limits (the objective's penalty is not a
    bound); ``ValueError`` when even the workspace centre needs more."""
    sine, cosine = design.coefficients(x)
    motion = design.trajectory(sine, cosine)
    ratio = design.torque_ratio(motion)
    shrink = 1.0
    while ratio > torque_fill and shrink > 1e-3:
        shrink *= 0.9
        motion = design.trajectory(sine * shrink, cosine * shrink)
        ratio = design.torque_ratio(motion)
    if ratio > torque_fill:
        raise ValueError(
            f"no reference within {torque_fill:.0%} of the torque limits: holding the "
            f"workspace centre alone takes {ratio:.0%} of them"
        )
    return sine * shrink, cosine * shrink, motion, ratio
