"""Rigid-arm velocity observers: Cristofaro & De Luca (2022), Nicosia-Tomei, Solsona & Puleston.

Paper scenarios on the envs TwoLinkRigid-v0 (Cristofaro & De Luca, Table I, encoder
quantization 7e-4) and TwoLinkRigidFriction-v0 (Solsona & Puleston, Appendix 2,
Coulomb + viscous friction, encoder noise sigma = 0.01), plus env-free checks of the
model bounds, the integrator and the hybrid gain logic.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import pytest

import elastic_gym  # noqa: F401
from elastic_gym.model import RobotModel
from elastic_gym.observers import ObserverWrapper, make_observer
from elastic_gym.observers.nicosia_tomei import NicosiaTomeiObserver
from elastic_gym.observers.reduced_order import ReducedOrderObserver
from elastic_gym.observers.rigid_common import RigidArmBounds, christoffel_tensor, rk4_period
from elastic_gym.observers.solsona_puleston import (
    SolsonaPulestonObserver,
    sufficient_gain_bound,
)
from elastic_gym.robots.catalog import get_robot

PI = np.pi
DT = 1e-3
RIGID = "elastic_gym/TwoLinkRigid-v0"
FRICTION = "elastic_gym/TwoLinkRigidFriction-v0"
# Cristofaro & De Luca, Sec. V: initial state and the torques (18), (19) of Examples 1, 2
EXAMPLE_START = {"q": [-2 * PI / 3, PI / 10], "dq": [-0.5, 1.0]}
EXAMPLE_1 = {"amplitude": [1.0, -1.0], "frequency": [0.5, 1.0]}
EXAMPLE_2 = {
    "amplitude": [1.0, 1.0],
    "frequency": [1.0, 2.0],
    "phase": [0.0, -PI / 2],
    "offset": [0.0, -1.0],
}
INITIAL_ERROR = float(np.hypot(0.5, 1.0))  # x_hat_2(0) = 0


@dataclass
class Rollout:
    position: np.ndarray  # (T, N) true q
    velocity: np.ndarray  # (T, N) true q'
    errors: dict[str, np.ndarray]  # estimate - truth of q', (T, N) per observer
    diagnostics: dict[str, list[dict]]
    observers: dict


def rollout(
    env_id, steps, observers, initial_state, velocity_estimate=None, driver=None, **env_kwargs
) -> Rollout:
    """Run several observers on one episode (same samples and torques for all)."""
    env = gym.make(env_id, episode_time=None, **env_kwargs)
    obs, info = env.reset(seed=0, options={"initial_state": initial_state})
    model = env.unwrapped.model
    built = {key: make_observer(name, model, DT, **opts) for key, (name, opts) in observers.items()}
    x0 = (
        None
        if velocity_estimate is None
        else np.concatenate([obs["link_position"], velocity_estimate])
    )
    for observer in built.values():
        observer.reset(obs, x0)
    n = model.n
    position, velocity = np.zeros((steps, n)), np.zeros((steps, n))
    errors = {key: np.zeros((steps, n)) for key in built}
    diagnostics = {key: [] for key in built}
    for i in range(steps):
        action = np.zeros(n) if driver is None else driver(env.unwrapped, info)
        obs, _, terminated, _, info = env.step(action)
        assert not terminated, info["termination_reason"]
        position[i], velocity[i] = info["true_state"]["q"], info["true_state"]["dq"]
        for key, observer in built.items():
            errors[key][i] = observer.update(obs, info["torque"], DT)[n:] - velocity[i]
            diagnostics[key].append(dict(observer.diagnostics))
    env.close()
    return Rollout(position, velocity, errors, diagnostics, built)


def settling_time(error: np.ndarray, threshold: float) -> float:
    """Time after which |error| stays below ``threshold`` (s)."""
    above = np.nonzero(np.linalg.norm(error, axis=1) > threshold)[0]
    return (above[-1] + 1) * DT if len(above) else 0.0


def rms(error: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(error**2, axis=1))))


# ------------------------------------------------------------------ model bounds
@pytest.fixture(scope="module")
def rigid_model() -> RobotModel:
    return RobotModel(get_robot("two_link_rigid"))


def dense_coriolis_norm(model: RobotModel, q: np.ndarray, samples: int = 2001) -> float:
    """max over unit u of ||C(q, u)||_2 with pinocchio's C and dense sampling of the circle."""
    angles = np.linspace(0.0, PI, samples)
    C1, C2 = (model.coriolis_matrix(q, e) for e in np.eye(2))  # C(q, u) is linear in u
    matrices = np.cos(angles)[:, None, None] * C1 + np.sin(angles)[:, None, None] * C2
    return float(np.linalg.norm(matrices, 2, axis=(1, 2)).max())


def test_coriolis_bound_is_the_norm_maximum_and_scales_with_sin_q2(rigid_model):
    bounds = RigidArmBounds.from_model(rigid_model)
    for k in (10, 45, 100, 150):
        q = bounds.configurations[k]
        assert bounds.c0[k] == pytest.approx(dense_coriolis_norm(rigid_model, q), rel=1e-6)
    # planar 2R: C = h [[-u2, -(u1 + u2)], [u1, 0]] with h = m2 l1 lc2 sin q2 = 15 sin q2
    angles = np.linspace(0.0, PI, 2001)
    kappa = max(
        np.linalg.norm([[-np.sin(a), -np.cos(a) - np.sin(a)], [np.cos(a), 0.0]], 2) for a in angles
    )
    s = np.abs(np.sin(bounds.configurations[:, 1]))
    np.testing.assert_allclose(bounds.c0, 15.0 * kappa * s, rtol=1e-6, atol=1e-9)


def test_k0_of_example_1_from_an_independent_grid(rigid_model):
    """Eq. (12) with eta = 1, v_max = 2 and F = diag(0.1, 0.3), recomputed with pinocchio's C."""
    observer = ReducedOrderObserver(rigid_model, DT, eta=1.0, v_max=2.0)
    q2 = np.linspace(-PI, PI, 181)
    ratios = []
    for angle in q2:
        q = np.array([0.0, angle])
        lam = np.linalg.eigvalsh(rigid_model.mass_matrix(q))[0]
        ratios.append((dense_coriolis_norm(rigid_model, q) * 3.0 - 0.1) / lam)
    assert observer.k0 == pytest.approx(max(ratios), rel=1e-5)
    assert observer.k0 == pytest.approx(16.03, abs=0.01)


def test_christoffel_tensor_on_a_spatial_arm():
    """KR15 (3 joints, spatial): identity (3), C q' = n - g, M' - 2C skew, c0 bounds ||C||."""
    model = RobotModel(get_robot("kr15_elastic"))
    rng = np.random.default_rng(0)
    q, dq, u, w = rng.normal(size=(4, 3))
    T = christoffel_tensor(model, q)
    np.testing.assert_allclose((T @ u) @ w, (T @ w) @ u, atol=1e-10)
    np.testing.assert_allclose(
        (T @ dq) @ dq, model.nonlinear_effects(q, dq) - model.gravity(q), atol=1e-10
    )
    h = 1e-6
    Mdot = (model.mass_matrix(q + h * dq) - model.mass_matrix(q - h * dq)) / (2 * h)
    N = Mdot - 2 * (T @ dq)
    np.testing.assert_allclose(N, -N.T, atol=1e-6)
    bounds = RigidArmBounds.from_model(model, points_per_joint=5)
    assert bounds.configurations.shape == (25, 3)
    assert np.all(bounds.configurations[:, 0] == 0.0)
    directions = rng.normal(size=(500, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    for k in range(0, 25, 6):
        norms = np.linalg.norm(
            np.einsum("abc,sc->sab", bounds.tensors[k], directions), 2, axis=(1, 2)
        )
        assert norms.max() <= bounds.c0[k] * (1 + 1e-9)
        assert norms.max() >= 0.95 * bounds.c0[k]


def test_rk4_period_with_linear_hold_is_exact_for_polynomials():
    """x' = y(t) with y linear in t: the trapezoid is exact; x' = -a x + y matches expm."""
    y0, y1 = np.array([1.0, -2.0]), np.array([3.0, 0.5])
    x = rk4_period(lambda x, y, tau: y, np.zeros(2), y0, y1, None, 0.1)
    np.testing.assert_allclose(x, 0.05 * (y0 + y1), atol=1e-15)
    a, b, dt = 5.0, 0.5, 0.01
    x = rk4_period(
        lambda x, y, tau: -a * x + y + tau,
        np.array([1.0]),
        np.array([0.0]),
        np.array([1.0]),
        np.array([b]),
        dt,
        substeps=2,
    )
    slope = 1.0 / dt  # x' = -a x + slope t + b, x(0) = 1: x = alpha t + beta + (1 - beta) e^-at
    alpha = slope / a
    beta = (b - alpha) / a
    assert x[0] == pytest.approx(alpha * dt + beta + (1.0 - beta) * np.exp(-a * dt), abs=1e-9)


# ------------------------------------------------------------------ interface
def test_registry_names_and_option_errors(rigid_model):
    for name, cls in (
        ("reduced-order", ReducedOrderObserver),
        ("nicosia-tomei", NicosiaTomeiObserver),
        ("solsona-puleston", SolsonaPulestonObserver),
    ):
        observer = make_observer(name, rigid_model, DT)
        assert type(observer) is cls and observer.state_names == ("q", "dq")
        with pytest.raises(ValueError, match="rigid"):
            cls(RobotModel(get_robot("two_link_elastic")), DT)
    bad = [
        ("reduced-order", {"eta": -1.0}, ValueError, "eta"),
        ("reduced-order", {"jump_sets": "loose"}, ValueError, "jump_sets"),
        ("reduced-order", {"hybrid": True, "k0": 5.0}, ValueError, "k0"),
        ("reduced-order", {"hybrid": "yes"}, TypeError, "hybrid"),
        ("reduced-order", {"r0": 0}, ValueError, "r0"),
        ("nicosia-tomei", {"kD": "fast"}, TypeError, "kD"),
        ("nicosia-tomei", {"kP": 0.0}, ValueError, "kP"),
        ("solsona-puleston", {"g0": np.inf}, ValueError, "g0"),
        ("solsona-puleston", {"model_friction": 1}, TypeError, "model_friction"),
        ("solsona-puleston", {"substeps": 0}, ValueError, "substeps"),
    ]
    for name, options, error, word in bad:
        with pytest.raises(error, match=word):
            make_observer(name, rigid_model, DT, **options)


def test_nicosia_tomei_defaults_to_the_reduced_order_gain(rigid_model):
    ro = ReducedOrderObserver(rigid_model, DT)
    nt = NicosiaTomeiObserver(rigid_model, DT)
    assert nt.kD == ro.k0
    assert nt.kP == pytest.approx(0.25 * ro.k0**2 * ro.bounds.lambda_max.max())


def test_observer_wrapper_runs_the_reduced_order_observer():
    env = ObserverWrapper(
        gym.make(RIGID, task="excitation", task_options=EXAMPLE_1), "reduced-order", hybrid=True
    )
    obs, info = env.reset(seed=0, options={"initial_state": EXAMPLE_START})
    np.testing.assert_allclose(obs["state"][2:], 0.0)
    for _ in range(300):
        obs, *_, info = env.step(np.zeros(2))
    assert np.linalg.norm(info["estimation_error"][2:]) < 0.05
    assert set(info["observer_diagnostics"]) == {"gain", "r", "jumps"}
    env.close()


# ------------------------------------------------------------------ Cristofaro & De Luca
@pytest.mark.slow
def test_lyapunov_function_decays_at_rate_2k0_without_quantization():
    """Theorem 1: V = 1/2 e^T M(y) e decreases monotonically, at ~2 k0 (error eq. -k0 e + ...)."""
    run = rollout(
        RIGID,
        400,
        {"ro": ("reduced-order", {})},
        EXAMPLE_START,
        task="excitation",
        task_options=EXAMPLE_1,
        encoder={"resolution": 0.0},
    )
    k0 = run.observers["ro"].k0
    model = RobotModel(get_robot("two_link_rigid"))
    V = np.array(
        [
            0.5 * e @ model.mass_matrix(q) @ e
            for e, q in zip(run.errors["ro"], run.position, strict=True)
        ]
    )
    assert np.all(np.diff(V) < 0.0)
    rate = -np.log(V[300] / V[0]) / (300 * DT)
    assert rate == pytest.approx(2.0 * k0, rel=0.1)


@pytest.fixture(scope="module")
def example_1() -> Rollout:
    return rollout(
        RIGID,
        2000,
        {"ro": ("reduced-order", {}), "nt": ("nicosia-tomei", {})},
        EXAMPLE_START,
        task="excitation",
        task_options=EXAMPLE_1,
    )


def test_example_1_reduced_order_converges_faster_than_nicosia_tomei(example_1):
    run = example_1
    assert run.observers["nt"].kD == run.observers["ro"].k0  # equal injection gain
    t_ro = settling_time(run.errors["ro"], 0.01 * INITIAL_ERROR)
    t_nt = settling_time(run.errors["nt"], 0.01 * INITIAL_ERROR)
    assert 0.0 < t_ro < 0.8 * t_nt < 0.8
    late_ro, late_nt = rms(run.errors["ro"][1000:]), rms(run.errors["nt"][1000:])
    assert late_ro < 0.01 and late_nt < 0.01
    # Sec. V: the reduced-order observer is more sensitive to quantization (feedthrough k0 y)
    assert late_ro > 2.0 * late_nt


def test_example_1_with_heavier_links_still_converges():
    """Example 1b: plant link masses +10 %, observers on the nominal model."""
    run = rollout(
        RIGID,
        3000,
        {"ro": ("reduced-order", {})},
        EXAMPLE_START,
        task="excitation",
        task_options=EXAMPLE_1,
        plant_scaling={"link_mass": 1.1},
    )
    error = run.errors["ro"]
    peak_speed = np.linalg.norm(run.velocity, axis=1).max()
    assert settling_time(error, 0.2 * INITIAL_ERROR) < 0.5
    assert rms(error[1000:]) < 0.06 * peak_speed
    assert np.linalg.norm(error[1000:], axis=1).max() < 0.15


@pytest.mark.slow
def test_example_2_hybrid_gain_schedules_without_chattering():
    """Example 2 (eq. 19): r rises with the speed, a handful of jumps; literal sets chatter."""
    steps = 7000
    run = rollout(
        RIGID,
        steps,
        {
            "hybrid": ("reduced-order", {"hybrid": True}),
            "literal": ("reduced-order", {"hybrid": True, "jump_sets": "literal"}),
        },
        EXAMPLE_START,
        task="excitation",
        task_options=EXAMPLE_2,
    )
    r = np.array([d["r"] for d in run.diagnostics["hybrid"]])
    gain = np.array([d["gain"] for d in run.diagnostics["hybrid"]])
    jumps = run.diagnostics["hybrid"][-1]["jumps"]
    observer = run.observers["hybrid"]
    assert r.max() == 2 and 1 <= jumps <= 6
    np.testing.assert_allclose(gain[r == 2], observer.bounds.injection_gain(1.0 + 2 * 2.0))
    np.testing.assert_allclose(gain[r == 1], observer.k0)  # k_1 of (16) = k0 of (12), v_max = 2
    assert np.linalg.norm(run.errors["hybrid"][500:], axis=1).max() < 0.03
    assert run.diagnostics["literal"][-1]["jumps"] == steps  # a jump at every sample


def constant_speed_ramp(model: RobotModel, peak: float, duration: float):
    """Samples y_k and held torques of an exact motion q = q0 + d S(t), |q'| = s(t) = peak sin."""
    direction = np.array([0.6, 0.8])
    t = np.arange(int(duration / DT) + 1) * DT
    w = PI / duration
    position = np.array([0.3, -0.5]) + np.outer(peak / w * (1 - np.cos(w * t)), direction)
    mid = t[:-1] + 0.5 * DT
    torques = [
        model.rnea(
            np.array([0.3, -0.5]) + peak / w * (1 - np.cos(w * s)) * direction,
            peak * np.sin(w * s) * direction,
            peak * w * np.cos(w * s) * direction,
        )
        + model.link_friction(peak * np.sin(w * s) * direction)
        for s in mid
    ]
    return position, np.array(torques), peak * np.abs(np.sin(w * t))


@pytest.mark.slow
def test_hybrid_jump_thresholds_and_continuity(rigid_model):
    """Jumps at |x_hat_2| = r v_bar - eta (up) and (r - 1) v_bar - eta - tolerance (down)."""
    position, torques, speed = constant_speed_ramp(rigid_model, 6.0, 6.0)
    observer = ReducedOrderObserver(rigid_model, DT, hybrid=True, tolerance=0.1)
    literal = ReducedOrderObserver(rigid_model, DT, hybrid=True, jump_sets="literal")
    estimates, levels = [observer.reset({"link_position": position[0]})[2:]], [1]
    literal.reset({"link_position": position[0]})
    for y, tau in zip(position[1:], torques, strict=True):
        estimates.append(observer.update({"link_position": y}, tau, DT)[2:])
        levels.append(observer.r)
        literal.update({"link_position": y}, tau, DT)
    estimates, levels = np.array(estimates), np.array(levels)
    assert np.abs(np.linalg.norm(estimates, axis=1) - speed).max() < 2e-3
    # continuity of x_hat_2 = z + k_r y across the jumps (z reset): steps as small as the truth's
    assert np.abs(np.diff(estimates, axis=0)).max() < 1.5 * np.abs(np.diff(speed)).max()
    change = np.nonzero(np.diff(levels))[0] + 1
    speeds = np.linalg.norm(estimates, axis=1)
    ups = [(levels[i - 1], speeds[i]) for i in change if levels[i] > levels[i - 1]]
    downs = [(levels[i - 1], speeds[i]) for i in change if levels[i] < levels[i - 1]]
    assert [r for r, _ in ups] == [1, 2, 3] and [r for r, _ in downs] == [4, 3, 2]
    for r, s in ups:
        assert r * 2.0 - 1.0 <= s < r * 2.0 - 1.0 + 0.01
    for r, s in downs:
        assert (r - 1) * 2.0 - 1.0 - 0.1 - 0.01 < s <= (r - 1) * 2.0 - 1.0 - 0.1
    assert observer.jumps == 6
    assert literal.jumps == len(position) - 1


# ------------------------------------------------------------------ Solsona & Puleston
def computed_torque(env, info) -> np.ndarray:
    """Feedback linearization on the true state with the plant model (as in their Sec. 4)."""
    plant, state, ref = env.plant_model, info["true_state"], info["reference"]
    q, dq = state["q"], state["dq"]
    acceleration = ref["ddq"] + 40.0 * (ref["dq"] - dq) + 400.0 * (ref["q"] - q)
    return (
        plant.mass_matrix(q) @ acceleration
        + plant.nonlinear_effects(q, dq)
        + plant.link_friction(dq)
    )


@pytest.mark.slow
def test_solsona_puleston_example_converges_although_g0_is_below_their_bound():
    g0, sigma = 3.0, 0.01
    run = rollout(
        FRICTION,
        4000,
        {
            "sp": ("solsona-puleston", {"g0": g0}),
            "no_friction": ("solsona-puleston", {"g0": g0, "model_friction": False}),
        },
        {"q": [PI / 10, PI / 8], "dq": [0.0, 0.0]},
        velocity_estimate=np.array([1.2, 1.4]),
        driver=computed_torque,
        task="tracking",
        task_options={
            "start": [PI / 10, PI / 8],
            "waypoints": [[-0.5, 1.0], [0.6, -0.4]],
            "move_time": 1.0,
            "dwell_time": 0.3,
        },
    )
    error = run.errors["sp"]
    initial = np.hypot(1.2, 1.4)
    assert settling_time(error, 0.1 * initial) < 1.0
    late = rms(error[2000:])
    # the floor is the encoder noise fed through x_hat_2 = v + g0 y: ~ g0 sigma sqrt(N)
    assert 0.5 * g0 * sigma * np.sqrt(2) < late < 2.0 * g0 * sigma * np.sqrt(2)
    assert rms(run.errors["no_friction"][2000:]) > 1.0  # Pitfall: friction must be modelled
    # their sufficient condition (17), r2 = r1 + |e(t0)| of eq. (14): g0 = 3 does not satisfy it
    r1 = np.linalg.norm(run.velocity, axis=1).max()
    bound = sufficient_gain_bound(RobotModel(get_robot("two_link_friction")), r1 + initial)
    assert bound > 2 * g0
