"""De Luca et al. (2007) acceleration-based observer: Theorems 1 and 2, Remark 3, eq. (12).

The env is run open loop (``excitation`` task: gravity compensation plus a sine that
starts at zero) and every measurement is recorded, so that several observers can be
run on exactly the same data.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm
from scipy.optimize import brentq, linear_sum_assignment

import elastic_gym  # noqa: F401
from elastic_gym.model import RobotModel
from elastic_gym.observers import ObserverWrapper, make_observer
from elastic_gym.observers.deluca import DeLucaObserver, foh_discretization
from elastic_gym.observers.deluca_gains import butterworth_poles
from elastic_gym.robots.catalog import get_robot

TWO_LINK = "elastic_gym/TwoLinkElastic-v0"
KR15 = "elastic_gym/KR15Elastic-v0"
IIWA = "elastic_gym/IiwaElastic-v0"
JOINTS = {TWO_LINK: 2, KR15: 3, IIWA: 7}
# ultimate |e| bound per block (theta, q, theta', q') of eq. (12) with the env's default sensors
ULTIMATE_BOUND = np.array([1e-5, 1.5e-4, 1e-2, 2e-2])
IDEAL_SENSORS = {"encoder": {"resolution": 0.0}, "accelerometer": "ideal"}


@dataclass
class Record:
    """One open-loop run: measurements (with the true q''), applied torques, true states."""

    model: RobotModel
    dt: float
    measurements: list[dict]
    torques: list[np.ndarray]
    states: np.ndarray  # (steps + 1, 4N)

    @property
    def n(self) -> int:
        return self.model.n


def record(
    env_id: str, steps: int, seed: int = 0, task_options: dict | None = None, **env_kwargs
) -> Record:
    n = JOINTS[env_id]
    options = {"phase": [-np.pi / 2] * n, **(task_options or {})}  # torque starts smoothly
    env = gym.make(env_id, task="excitation", task_options=options, episode_time=None, **env_kwargs)
    base = env.unwrapped

    def measurement(obs, info):
        return {**obs, "link_acceleration": info["true_state"]["ddq"].copy()}

    obs, info = env.reset(seed=seed)
    measurements, torques, states = [measurement(obs, info)], [], [info["true_state"]["x"]]
    for _ in range(steps):
        obs, _, terminated, _, info = env.step(np.zeros(n))
        assert not terminated, info["termination_reason"]
        measurements.append(measurement(obs, info))
        torques.append(info["torque"])
        states.append(info["true_state"]["x"])
    env.close()
    return Record(base.model, base.control_dt, measurements, torques, np.array(states))


def run_observer(observer: DeLucaObserver, rec: Record, initial_estimate=None) -> np.ndarray:
    """Estimates (steps + 1, 4N) of an observer on a recorded run."""
    estimates = [observer.reset(rec.measurements[0], initial_estimate)]
    for obs, tau in zip(rec.measurements[1:], rec.torques, strict=True):
        estimates.append(observer.update(obs, tau, rec.dt))
    return np.array(estimates)


def initial_error(n: int, seed: int = 1) -> np.ndarray:
    """e(0) = x(0) - xi(0): 10 mrad on positions, 0.3 rad/s on velocities."""
    rng = np.random.default_rng(seed)
    scale = np.repeat([0.01, 0.01, 0.3, 0.3], n)
    return scale * rng.uniform(-1.0, 1.0, 4 * n)


def blocks(e: np.ndarray, n: int) -> np.ndarray:
    """(steps, 4N) -> (steps, 4, N): theta, q, theta', q' blocks."""
    return e.reshape(len(e), 4, n)


# ---------------------------------------------------------------------- design
@pytest.mark.parametrize("robot", ["two_link_elastic", "kr15_elastic", "iiwa_elastic"])
def test_closed_form_gains_place_the_assigned_poles(robot):
    model = RobotModel(get_robot(robot))
    n = model.n
    rng = np.random.default_rng(2)
    radius = rng.uniform(100.0, 400.0, (n, 1))
    per_joint = np.hstack(
        [
            -radius,
            -2.0 * radius,
            radius * (-0.5 + 0.8j),
            radius * (-0.5 - 0.8j),
        ]
    )
    for poles in (None, per_joint):
        observer = DeLucaObserver(model, 1e-3, acceleration="ideal", poles=poles)
        expected = observer.poles.ravel()
        eig = np.linalg.eigvals(observer.A_obs)
        rows, cols = linear_sum_assignment(np.abs(eig[:, None] - expected[None, :]))
        np.testing.assert_allclose(eig[rows], expected[cols], rtol=1e-6)
        assert observer.gains.shape == (4, n) and np.all(np.isfinite(observer.gains))
    # A_obs is block-decoupled per joint (Remark 2): joint i never sees joint j != i
    coupling = np.abs(observer.A_obs.reshape(4, n, 4, n)).sum(axis=(0, 2))
    assert np.all(coupling[~np.eye(n, dtype=bool)] == 0.0)


def test_default_poles_are_a_butterworth_pattern_of_radius_250():
    model = RobotModel(get_robot("two_link_elastic"))
    observer = DeLucaObserver(model, 1e-3, acceleration="ideal")
    poles = observer.poles
    np.testing.assert_allclose(np.abs(poles), 250.0)
    damping = np.sort(-poles.real / np.abs(poles), axis=1)
    c1, c2 = np.cos(3 * np.pi / 8), np.cos(np.pi / 8)
    np.testing.assert_allclose(damping, np.tile([c1, c1, c2, c2], (2, 1)), atol=1e-12)
    per_joint = DeLucaObserver(model, 1e-3, acceleration="ideal", bandwidth=[200.0, 300.0])
    np.testing.assert_allclose(np.abs(per_joint.poles), [[200.0] * 4, [300.0] * 4])
    np.testing.assert_allclose(butterworth_poles(250.0, 2), poles)


def test_foh_discretization_is_exact_for_inputs_linear_between_samples():
    rng = np.random.default_rng(3)
    F = rng.normal(size=(4, 4)) - 3.0 * np.eye(4)
    E = rng.normal(size=(4, 2))
    T, x0, w0, w1 = 0.05, rng.normal(size=4), rng.normal(size=2), rng.normal(size=2)
    phi, p0, p1 = foh_discretization(F, E, T)

    def rhs(t, x):
        return F @ x + E @ (w0 + (w1 - w0) * t / T)

    exact = solve_ivp(rhs, (0.0, T), x0, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
    np.testing.assert_allclose(phi @ x0 + p0 @ w0 + p1 @ w1, exact, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(phi, expm(F * T), rtol=1e-13)


# ---------------------------------------------------------------------- Theorem 1
@pytest.mark.parametrize("env_id", [TWO_LINK, IIWA])
@pytest.mark.parametrize("link_mass", [1.0, 1.3, 0.7])
def test_theorem1_error_follows_the_assigned_linear_dynamics(env_id, link_mass):
    """e(t) = exp(A_obs t) e(0) with ideal q'', whatever the (unmodelled) link masses."""
    rec = record(env_id, 150, plant_scaling={"link_mass": link_mass}, **IDEAL_SENSORS)
    n = rec.n
    observer = DeLucaObserver(rec.model, rec.dt, acceleration="ideal")
    e0 = initial_error(n)
    errors = rec.states - run_observer(observer, rec, rec.states[0] - e0)
    predicted = np.array([expm(observer.A_obs * k * rec.dt) @ e0 for k in range(len(errors))])
    peak = np.abs(blocks(predicted, n)).max(axis=(0, 2))
    deviation = np.abs(blocks(errors - predicted, n)).max(axis=(0, 2))
    # measured: <= 0.3 % of each block's peak (the plant's own Euler integration)
    assert np.all(deviation < 1e-2 * peak), deviation / peak


@pytest.mark.parametrize(
    ("env_id", "link_mass"),
    [(TWO_LINK, 1.3), (TWO_LINK, 0.7), pytest.param(KR15, 1.3, marks=pytest.mark.slow)],
)
def test_superposition_gives_the_discrete_error_map(env_id, link_mass):
    """Two runs on the same data differ by Phi^k e(0), Phi = expm(A_obs T) (Thms 1 and 2)."""
    rec = record(env_id, 120, plant_scaling={"link_mass": link_mass})
    observer = DeLucaObserver(rec.model, rec.dt, acceleration="ideal")
    e0 = initial_error(rec.n)
    start = rec.states[0]
    difference = run_observer(observer, rec, start) - run_observer(observer, rec, start - e0)
    phi = observer.phi
    np.testing.assert_allclose(phi, expm(observer.A_obs * rec.dt), rtol=1e-12, atol=1e-14)
    discrete = [e0]
    for _ in range(len(difference) - 1):
        discrete.append(phi @ discrete[-1])
    peak = np.abs(difference).max()  # the error map peaks at ~25 |e(0)|
    np.testing.assert_allclose(difference, np.array(discrete), rtol=0, atol=1e-12 * peak)
    continuous = np.array([expm(observer.A_obs * k * rec.dt) @ e0 for k in (10, 60, 120)])
    np.testing.assert_allclose(difference[[10, 60, 120]], continuous, rtol=0, atol=1e-12 * peak)


def test_ideal_variant_through_the_wrapper_uses_only_the_privileged_link_acceleration():
    env = gym.make(TWO_LINK, task="excitation", **IDEAL_SENSORS)
    wrapped = ObserverWrapper(env, "deluca-ideal", bandwidth=300.0)
    assert wrapped.observer.privileged == ("link_acceleration",)
    assert make_observer("deluca", env.unwrapped.model, 1e-3).privileged == ()
    _, info = wrapped.reset(seed=4)
    for _ in range(100):
        _, _, _, _, info = wrapped.step(np.zeros(2))
    np.testing.assert_allclose(np.abs(wrapped.observer.poles), 300.0)
    error = info["estimation_error"]
    assert np.all(np.abs(error[:4]) < 1e-5) and np.all(np.abs(error[4:]) < 1e-2)
    np.testing.assert_array_equal(error, info["estimate"] - info["true_state"]["x"])
    env.close()


def test_default_initial_estimate_is_the_static_equilibrium():
    rec = record(KR15, 0, task_options={"start": [0.3, 0.2, -0.4]}, **IDEAL_SENSORS)
    model = rec.model
    n = model.n
    xi = DeLucaObserver(model, rec.dt).reset(rec.measurements[0])
    theta, q = xi[:n], xi[n : 2 * n]
    np.testing.assert_allclose(theta, rec.measurements[0]["motor_position"])
    np.testing.assert_allclose(theta, q + model.gravity(q) / model.K, atol=1e-12)
    np.testing.assert_allclose(q, rec.states[0][n : 2 * n], atol=1e-10)
    assert np.all(xi[2 * n :] == 0.0)


# ---------------------------------------------------------------------- Theorem 2
def test_theorem2_needs_the_coupling_term_on_model_2():
    """KR15 (S23 != 0): without -B^-1 S^T y2 the q3 estimate is off by S23 q2'' / K3."""
    # joint 2 excited with 10 % of its torque limit (default 5 %): larger q2''
    rec = record(KR15, 800, task_options={"amplitude": [125.0, 400.0, 90.0]}, **IDEAL_SENSORS)
    n, model = rec.n, rec.model
    e0 = initial_error(n)
    window = slice(200, None)
    rms = {}
    for use_coupling in (True, False):
        observer = DeLucaObserver(model, rec.dt, acceleration="ideal", use_coupling=use_coupling)
        errors = blocks(rec.states - run_observer(observer, rec, rec.states[0] - e0), n)
        rms[use_coupling] = np.sqrt(np.mean(errors[window] ** 2, axis=0))
        if not use_coupling:
            ddq2 = np.array([m["link_acceleration"][1] for m in rec.measurements])
            quasi_static = model.S[1, 2] * ddq2 / model.K[2]
            residual = errors[window, 1, 2] - quasi_static[window]
            rms_static = np.sqrt(np.mean(quasi_static[window] ** 2))
            assert np.sqrt(np.mean(residual**2)) < 0.15 * rms_static
    with_s, without_s = rms[True], rms[False]
    assert np.all(with_s[:2] < 1e-5)  # theta, q: converged to the plant-integration level
    # measured RMS ratio ~25 on q3; the other joints have no coupling and are unaffected
    assert without_s[1, 2] > 8.0 * with_s[1, 2]
    np.testing.assert_allclose(without_s[1, :2], with_s[1, :2], rtol=1e-6)


# ---------------------------------------------------------------------- eq. (12)
@pytest.mark.parametrize("env_id", [TWO_LINK, KR15])
def test_accelerometer_observer_is_ultimately_bounded_with_noise_and_bias(env_id):
    """Eq. (12) with the env's MEMS noise and bias and the quantized encoders.

    Measured |e| after 0.2 s (seed 5), blocks (theta, q, theta', q'):
    TwoLink (3.8e-6, 3.8e-5, 2.8e-3, 5.0e-3), KR15 (3.8e-6, 5.5e-5, 2.8e-3, 7.0e-3).
    """
    rec = record(env_id, 800, seed=5)
    n = rec.n
    observer = DeLucaObserver(rec.model, rec.dt, acceleration="accelerometer")
    errors = blocks(rec.states - run_observer(observer, rec, rec.states[0] - initial_error(n)), n)
    ultimate = np.abs(errors[200:]).max(axis=(0, 2))
    assert np.all(ultimate < ULTIMATE_BOUND), ultimate
    assert not observer.diagnostics["near_singular"]


def test_velocity_saturation_prevents_peaking_escape_of_eq12():
    """From a large initial error the velocity peaking enters W_A quadratically (KR15)."""
    rec = record(KR15, 300, seed=5)
    start = rec.states[0] - 10.0 * initial_error(rec.n)  # 0.1 rad, 3 rad/s
    with np.errstate(all="ignore"):
        plain = run_observer(
            DeLucaObserver(rec.model, rec.dt, velocity_saturation=None), rec, start
        )
    assert not np.all(np.isfinite(plain[-1])) or np.abs(plain[-1] - rec.states[-1]).max() > 1.0
    saturated = DeLucaObserver(rec.model, rec.dt, velocity_saturation=10.0)
    errors = rec.states - run_observer(saturated, rec, start)
    final = np.abs(blocks(errors, rec.n)[-50:]).max(axis=(0, 2))
    assert np.all(final < ULTIMATE_BOUND), final


def kr15_singular_configurations(model: RobotModel) -> dict[str, np.ndarray]:
    """Fig. 2: sensor above axis 1, or on the line through axes 2 and 3."""

    def points(q):
        sensor = model.sensor_placements(q)[0].translation
        axis2, axis3 = (model.data.oMi[j].translation for j in (2, 3))
        return sensor, axis2, axis3

    def radial(q3):  # horizontal offset of the sensor from axis 1 (in the arm plane)
        return points(np.array([0.0, 0.0, q3]))[0][0]

    def collinear(q3):  # (sensor - axis3) x (axis3 - axis2) along the axis direction y
        sensor, axis2, axis3 = points(np.array([0.0, 0.2, q3]))
        return np.cross(sensor - axis3, axis3 - axis2)[1]

    return {
        "above axis 1": np.array([0.3, 0.0, brentq(radial, -2.5, -1.5, xtol=1e-14)]),
        "aligned with axes 2, 3": np.array([0.3, 0.2, brentq(collinear, -1.6, -1.0, xtol=1e-14)]),
    }


def test_kr15_singular_configurations_are_flagged_and_damped():
    model = RobotModel(get_robot("kr15_elastic"))
    for q in kr15_singular_configurations(model).values():
        T, _ = model.accelerometer_maps(q, np.zeros(3))
        assert np.linalg.svd(T, compute_uv=False)[-1] < 1e-9
    configs = kr15_singular_configurations(model)
    still = {"amplitude": 0.0}
    for name, q in configs.items():
        rec = record(KR15, 30, task_options={**still, "start": q.tolist()})
        observer = DeLucaObserver(rec.model, rec.dt)
        run_observer(observer, rec)
        diag = observer.diagnostics
        assert diag["near_singular"] and diag["sigma_min_TA"] < 1e-3, (name, diag)
        assert diag["cond_TA"] > 1e3 and diag["dls_damping"] > 0.9 * observer.dls_damping
    rec = record(KR15, 30, task_options={**still, "start": [0.3, 0.2, -0.3]})
    observer = DeLucaObserver(rec.model, rec.dt)
    run_observer(observer, rec)
    assert not observer.diagnostics["near_singular"] and observer.diagnostics["cond_TA"] < 10.0
    assert observer.diagnostics["dls_damping"] == 0.0

    # moving through the aligned singularity with MEMS noise: DLS bounded, plain inverse not
    limit = np.asarray(get_robot("kr15_elastic").torque_limit)
    moving = {
        "start": configs["aligned with axes 2, 3"].tolist(),
        "amplitude": (0.01 * limit).tolist(),
        "frequency": [2.0, 3.0, 4.0],
    }
    rec = record(KR15, 400, seed=3, task_options=moving)
    damped = rec.states - run_observer(DeLucaObserver(rec.model, rec.dt), rec)
    plain = rec.states - run_observer(
        DeLucaObserver(rec.model, rec.dt, dls_threshold=1e-12, dls_damping=1e-12), rec
    )
    velocity_error = np.abs(blocks(damped, 3)[:, 3]).max()
    assert velocity_error < 0.1
    plain_error = np.abs(blocks(plain, 3)[:, 3]).max()
    assert not np.isfinite(plain_error) or plain_error > 10.0 * velocity_error


# ---------------------------------------------------------------------- input checks
def test_bad_options_and_inputs_raise_clear_errors():
    model = RobotModel(get_robot("two_link_elastic"))
    bad = [
        ({"acceleration": "gyro"}, "acceleration"),
        ({"poles": [-1.0, -2.0, -3.0]}, "poles"),
        ({"poles": [-1.0, -2.0, 3.0, -4.0]}, "negative real parts"),
        ({"poles": "fast"}, "poles must be finite numbers"),
        ({"poles": [-1 + 1j, -1 + 1j, -2.0, -3.0]}, "conjugate"),
        (
            {"poles": [-1.0] * 4, "bandwidth": 100.0},
            "one of poles or bandwidth, not poles and bandwidth",
        ),
        ({"bandwidth": -5.0}, "bandwidth"),
        ({"dls_threshold": 0.0}, "dls_threshold"),
        ({"dls_damping": float("nan")}, "dls_damping"),
        ({"velocity_saturation": -1.0}, "velocity_saturation"),
    ]
    for options, match in bad:
        with pytest.raises(ValueError, match=match):
            DeLucaObserver(model, 1e-3, **options)
    with pytest.raises(TypeError, match="use_coupling"):
        DeLucaObserver(model, 1e-3, use_coupling="yes")
    with pytest.raises(ValueError, match="applies to"):
        DeLucaObserver(RobotModel(get_robot("two_link_rigid")), 1e-3)
    with pytest.raises(ValueError, match="M >= N"):
        DeLucaObserver(model.with_accelerometers(()), 1e-3)

    observer = DeLucaObserver(model, 1e-3, acceleration="ideal")
    obs = {"motor_position": np.zeros(2), "acceleration": np.zeros(6)}
    with pytest.raises(ValueError, match="link_acceleration"):
        observer.reset(obs)
    observer.reset({**obs, "link_acceleration": np.zeros(2)})
    with pytest.raises(ValueError, match="dt"):
        observer.update({**obs, "link_acceleration": np.zeros(2)}, np.zeros(2), 2e-3)
    with pytest.raises(ValueError, match="torque"):
        observer.update({**obs, "link_acceleration": np.zeros(2)}, np.zeros(3), 1e-3)
    accel = DeLucaObserver(model, 1e-3)
    with pytest.raises(ValueError, match="acceleration"):
        accel.reset({"motor_position": np.zeros(2), "acceleration": np.zeros(5)})


def test_every_arm_in_place_update_is_the_checked_path_bit_for_bit():
    """One `update_arms` of every arm (in place, on the env's float64 rows), the same
    periods through the checked and copying path (`arms` given) and `update_sequence` (one
    compiled call) give the same estimates and eq. (11) diagnostics to the last bit."""
    envs = gym.make_vec(
        "elastic_gym/TwoLinkElastic-v0", num_envs=3, vectorization_mode="vector_entry_point"
    )
    obs, _ = envs.reset(seed=4)
    model, dt = envs.unwrapped.model, envs.unwrapped.control_dt
    rng = np.random.default_rng(0)
    limit = envs.unwrapped.torque_limit
    keys = ("motor_position", "acceleration")
    steps = []
    for _ in range(40):
        tau = 0.1 * limit * rng.uniform(-1, 1, (3, len(limit)))
        measured = envs.step(tau)[0]
        steps.append(({key: measured[key].copy() for key in keys}, tau))
    envs.close()
    every, subset, sequence = (DeLucaObserver(model, dt) for _ in range(3))
    for observer in (every, subset, sequence):
        observer.reset_arms(obs, np.arange(3))
    for measured, tau in steps:
        fast = every.update_arms(measured, tau, dt)
        assert np.array_equal(fast, subset.update_arms(measured, tau, dt, np.arange(3)))
        for key, value in every.arm_diagnostics.items():
            assert np.array_equal(value, subset.arm_diagnostics[key]), key
    periods = {key: np.stack([m[key] for m, _ in steps]) for key in keys}
    estimates = sequence.update_sequence(periods, np.stack([t for _, t in steps]), dt)
    assert np.array_equal(estimates[-1], fast)
    assert not np.array_equal(estimates[0], estimates[-1])  # the arms moved
