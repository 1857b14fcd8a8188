"""Extended Kalman filter (Abdeetedal / Lightcap & Banks eqs. (1)-(18)) on the elastic arms."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pinocchio as pin
import pytest
from helpers import fast_lane
from scipy.integrate import quad_vec
from scipy.linalg import expm

import elastic_gym  # noqa: F401
from elastic_gym.model import RobotModel
from elastic_gym.observers import ObserverWrapper, make_observer
from elastic_gym.observers.ekf import ExtendedKalmanFilter, covariance_option
from elastic_gym.robots.catalog import get_robot

DT = 1e-3
Q_ERROR, DQ_ERROR = 0.03, 0.5  # wrong initial link position (rad) and velocity (rad/s)


@pytest.fixture(scope="module", params=["two_link_elastic", "kr15_elastic", "iiwa_elastic"])
def model(request) -> RobotModel:
    return RobotModel(get_robot(request.param))


def random_state(model: RobotModel, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    n = model.n
    q = rng.uniform(model.spec.workspace_low, model.spec.workspace_high)
    x = np.concatenate(
        [q + 0.02 * rng.standard_normal(n), q, rng.normal(size=n), rng.normal(size=n)]
    )
    return x, 0.1 * model.torque_limit * rng.uniform(-1.0, 1.0, n)


def central_difference(fun, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    eye = np.eye(x.size)
    return np.column_stack([(fun(x + eps * e) - fun(x - eps * e)) / (2 * eps) for e in eye])


# ------------------------------------------------------------------- Jacobians
def test_dynamics_jacobian_matches_finite_differences(model):
    """F = df/dx and the input column G[:, :N] = df/dtau of eq. (8), models (1) and (2)."""
    ekf = ExtendedKalmanFilter(model, DT)
    x, tau = random_state(model)
    F, G = ekf.linearization(x, tau)
    F_fd = central_difference(lambda z: model.elastic_dynamics(z, tau), x)
    np.testing.assert_allclose(F, F_fd, rtol=0, atol=1e-6 * np.abs(F_fd).max())
    B_fd = central_difference(lambda u: model.elastic_dynamics(x, u), tau)
    np.testing.assert_allclose(G[:, : model.n], B_fd, rtol=0, atol=1e-6 * np.abs(B_fd).max())
    # noise matrix: inverse of [[B, S^T], [S, M]], eq. (5) blockdiag(B^-1, M^-1) when S = 0
    n = model.n
    inertia = np.block([[np.diag(model.B), model.S.T], [model.S, model.mass_matrix(x[n : 2 * n])]])
    np.testing.assert_allclose(G[2 * n :] @ inertia, np.eye(2 * n), atol=1e-9)
    assert np.all(G[: 2 * n] == 0.0)


def test_measurement_jacobian_matches_finite_differences(model):
    """H of encoders + accelerometers, h = (theta, T_A(q) q''(x, u) + W_A(q, q'))."""
    ekf = ExtendedKalmanFilter(model, DT, use_accelerometers=True)
    x, tau = random_state(model)
    h, H = ekf.measurement_model(x, tau)
    n = model.n
    readings = model.accelerometer_readings(
        x[n : 2 * n], x[3 * n :], model.elastic_accelerations(x, tau)[1]
    )
    np.testing.assert_allclose(h, np.concatenate([x[:n], readings]), atol=1e-12)
    H_fd = central_difference(lambda z: ekf.measurement_model(z, tau)[0], x)
    np.testing.assert_allclose(H, H_fd, rtol=0, atol=1e-6 * np.abs(H_fd).max())


# ------------------------------------------------------------- prediction math
def test_van_loan_process_noise_and_exponential_weighting():
    """P^- = e^{2 alpha T} Phi P Phi^T + Q_d with Phi = expm(F T) and
    Q_d = int_0^T e^{Fs} G Q G^T e^{F^T s} ds (discrete eq. (15))."""
    model = RobotModel(get_robot("two_link_elastic"))
    x, tau = random_state(model)
    alpha = 7.0
    plain = ExtendedKalmanFilter(model, DT, alpha=0.0, P0=0.0)
    plain.reset({}, x)
    plain.predict(tau, DT)
    F, G = plain.linearization(x, tau)
    GQG = G @ plain.Q @ G.T
    Qd, _ = quad_vec(lambda s: expm(F * s) @ GQG @ expm(F * s).T, 0.0, DT, epsabs=0, epsrel=1e-10)
    np.testing.assert_allclose(plain.P, Qd, rtol=0, atol=1e-8 * np.abs(Qd).max())

    rng = np.random.default_rng(0)
    A = rng.standard_normal((8, 8))
    P0 = A @ A.T * 1e-3
    weighted = ExtendedKalmanFilter(model, DT, alpha=alpha, P0=P0, Q=0.0)
    weighted.reset({}, x)
    weighted.predict(tau, DT)
    Phi = expm(F * DT)
    expected = np.exp(2 * alpha * DT) * Phi @ P0 @ Phi.T
    np.testing.assert_allclose(weighted.P, expected, rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(weighted.x, plain.x, atol=0)  # alpha only weights the data


def test_predicted_mean_is_accurate_rk4():
    """The mean over one period with tau held agrees with a fine integration (ZOH exact)."""
    model = RobotModel(get_robot("kr15_elastic"))
    x, tau = random_state(model)
    ekf = ExtendedKalmanFilter(model, DT)
    ekf.reset({}, x)
    ekf.predict(tau, DT)
    fine = ExtendedKalmanFilter(model, DT, substeps=50)
    fine.reset({}, x)
    fine.predict(tau, DT)
    assert np.max(np.abs(ekf.x - fine.x)) < 1e-6 * np.max(np.abs(fine.x - x))


# ------------------------------------------------------------------- convergence
def run_from_wrong_estimate(env_id: str, steps: int, seed: int = 0, **options):
    """Open-loop excitation (gravity compensation + cosines) with the EKF in the loop,
    started at rest from a link estimate off by (Q_ERROR, DQ_ERROR)."""
    spec = get_robot(gym.spec(env_id).kwargs["robot"])
    start = 0.5 * (np.asarray(spec.workspace_low) + np.asarray(spec.workspace_high))
    env = gym.make(
        env_id, task="excitation", task_options={"start": start.tolist()}, episode_time=None
    )
    base = env.unwrapped
    n = base.model.n
    truth = np.concatenate([base.plant_model.static_motor_position(start), start, np.zeros(2 * n)])
    offset = np.zeros(4 * n)
    offset[n : 2 * n] = Q_ERROR * (-1.0) ** np.arange(n)
    offset[3 * n :] = DQ_ERROR
    wrapped = ObserverWrapper(env, "ekf", initial_estimate=truth + offset, **options)
    _, info = wrapped.reset(seed=seed)
    errors = [info["estimation_error"]]
    for _ in range(steps):
        _, _, terminated, _, info = wrapped.step(np.zeros(n))
        assert not terminated, info["termination_reason"]
        errors.append(info["estimation_error"])
    wrapped.close()
    return np.asarray(errors).reshape(len(errors), 4, n), wrapped.observer


def assert_converged(errors: np.ndarray, q_rms: float, dq_rms: float) -> None:
    """Over the second half of the run: RMS below the bounds, peaks below 3x the bounds."""
    initial = np.abs(errors[0]).max(axis=1)
    assert initial[1] == pytest.approx(Q_ERROR) and initial[3] == pytest.approx(DQ_ERROR)
    tail = errors[len(errors) // 2 :]
    rms = np.sqrt(np.mean(tail**2, axis=(0, 2)))
    peak = np.abs(tail).max(axis=(0, 2))
    assert rms[1] < q_rms and peak[1] < 3 * q_rms, f"link position error rms {rms[1]:.1e}"
    assert rms[3] < dq_rms and peak[3] < 3 * dq_rms, f"link velocity error rms {rms[3]:.1e}"
    assert rms[0] < 1e-5 and rms[2] < dq_rms  # motor side


def test_converges_two_link_from_motor_encoders():
    errors, ekf = run_from_wrong_estimate("elastic_gym/TwoLinkElastic-v0", 300)
    assert_converged(errors, q_rms=1.5e-4, dq_rms=0.015)  # 0.5 % and 3 % of the initial errors
    assert np.allclose(ekf.P, ekf.P.T, atol=0) and np.linalg.eigvalsh(ekf.P).min() > 0.0


def test_converges_two_link_with_accelerometers():
    errors, ekf = run_from_wrong_estimate(
        "elastic_gym/TwoLinkElastic-v0", 300, use_accelerometers=True
    )
    assert_converged(errors, q_rms=1.5e-4, dq_rms=0.015)
    assert ekf.R.shape == (2 + 6, 2 + 6)
    assert np.isfinite(ekf.diagnostics["nis"])


def test_converges_kr15_coupled_model():
    errors, _ = run_from_wrong_estimate("elastic_gym/KR15Elastic-v0", 150)
    assert_converged(errors, q_rms=1.5e-4, dq_rms=0.015)


# ------------------------------------------------------------------ interface
def test_default_initial_estimate_is_static_equilibrium():
    """At rest: theta from the encoder, q from theta = q + K^-1 g(q), velocities zero."""
    model = RobotModel(get_robot("kr15_elastic"))
    q = np.array([0.3, 0.2, -0.4])
    theta = model.static_motor_position(q)
    ekf = make_observer("ekf", model, DT)
    assert isinstance(ekf, ExtendedKalmanFilter)
    x0 = ekf.reset({"motor_position": theta})
    np.testing.assert_allclose(x0, np.concatenate([theta, q, np.zeros(6)]), atol=1e-10)


def test_encoder_covariance_from_quantization_and_noise():
    model = RobotModel(get_robot("two_link_elastic"))
    ekf = ExtendedKalmanFilter(model, DT, encoder_resolution=1e-3, encoder_noise_std=2e-4)
    np.testing.assert_allclose(np.diag(ekf.R), 1e-6 / 12 + 4e-8)


def test_covariance_option_forms():
    blocks = (2, 2)
    np.testing.assert_allclose(covariance_option(2.0, "Q", blocks), 2.0 * np.eye(4))
    np.testing.assert_allclose(np.diag(covariance_option([1.0, 3.0], "Q", blocks)), [1, 1, 3, 3])
    np.testing.assert_allclose(np.diag(covariance_option([1, 2, 3, 4], "Q", blocks)), [1, 2, 3, 4])


@pytest.mark.parametrize(
    ("options", "error", "word"),
    [
        ({"alpha": -1.0}, ValueError, "alpha"),
        ({"alpha": "fast"}, TypeError, "alpha"),
        ({"Q": np.ones(3)}, ValueError, "options.Q"),
        ({"Q": -np.eye(4)}, ValueError, "options.Q"),
        ({"P0": [1.0, -1.0, 1.0, 1.0]}, ValueError, "options.P0"),
        ({"R": 1e-6, "encoder_noise_std": 1e-3}, ValueError, "options.R: give at most one of R or"),
        ({"R": 0.0}, ValueError, "options.R"),
        ({"use_accelerometers": 1}, TypeError, "use_accelerometers"),
        ({"substeps": 0}, ValueError, "substeps"),
        ({"accelerometer_std": 0.0}, ValueError, "accelerometer_std"),
    ],
)
def test_bad_options_are_named(options, error, word):
    model = RobotModel(get_robot("two_link_elastic"))
    with pytest.raises(error, match=word):
        ExtendedKalmanFilter(model, DT, **options)


@pytest.mark.parametrize(
    ("options", "message"),
    [  # each of these overflowed, broke the covariance or hung before it was refused
        ({"alpha": 1e6}, r"options\.alpha: too fast .*must be <= 1/dt = 1000"),
        ({"alpha": 1e4}, r"options\.alpha: too fast .*must be <= 1/dt = 1000"),
        ({"P0": 1e10}, r"options\.P0: .*of magnitude <= 1e\+06"),
        ({"Q": 1e60}, r"options\.Q: .*of magnitude <= 1e\+06"),
        ({"R": [[1e-9, 2e7], [2e7, 1e-9]]}, r"options\.R: .*of magnitude <= 1e\+06"),
        (
            {"encoder_resolution": 1e300},
            r"options\.encoder_resolution: .*less than or equal to 1000",
        ),
        (
            {"accelerometer_std": 1e300, "use_accelerometers": True},
            r"options\.accelerometer_std: .*less than or equal to 1000",
        ),
        ({"substeps": 10**9}, r"options\.substeps: .*less than or equal to 100"),
        ({"alpha": float("inf")}, r"options\.alpha: .*finite number"),
        ({"Q": [[1.0, 2.0], [3.0, 4.0]]}, r"options\.Q: must be a scalar, 2 block values"),
        (
            {"R": [[1e-9, 1e-6], [1e-6, 1e-9]]},
            r"options\.R: must be symmetric positive definite",
        ),
    ],
)
def test_absurd_options_are_refused_with_their_name(options, message):
    model = RobotModel(get_robot("two_link_elastic"))
    with pytest.raises((TypeError, ValueError), match=message):
        ExtendedKalmanFilter(model, DT, **options)


BOUNDS = [{"alpha": 1.0 / DT}, {"P0": 1e6}, {"Q": 1e6}, {"R": 1e6}]


@pytest.mark.parametrize("options", fast_lane(BOUNDS, BOUNDS[0]))
def test_options_at_their_bounds_keep_the_estimate_finite(options):
    env = ObserverWrapper(
        gym.make("elastic_gym/TwoLinkElastic-v0", max_episode_steps=300), "ekf", **options
    )
    env.reset(seed=0)
    with np.errstate(over="raise", invalid="raise", divide="raise"):
        for _ in range(300):
            _, _, terminated, _, info = env.step(np.zeros(2))
            assert not terminated and np.all(np.isfinite(info["estimate"]))
    env.close()


def test_rejects_rigid_arms_and_missing_sensors():
    with pytest.raises(ValueError, match="elastic"):
        ExtendedKalmanFilter(RobotModel(get_robot("two_link_rigid")), DT)
    bare = RobotModel(get_robot("two_link_elastic")).with_accelerometers(())
    with pytest.raises(ValueError, match="use_accelerometers"):
        ExtendedKalmanFilter(bare, DT, use_accelerometers=True)
    ekf = ExtendedKalmanFilter(
        RobotModel(get_robot("two_link_elastic")), DT, use_accelerometers=True
    )
    ekf.reset({"motor_position": np.zeros(2)})
    with pytest.raises(ValueError, match="acceleration"):
        ekf.update({"motor_position": np.zeros(2)}, np.zeros(2), DT)


def pinocchio_acceleration_jacobian(model: RobotModel, x: np.ndarray, tau: np.ndarray):
    """d(theta'', q'')/dx of model (1)/(2) from pinocchio's analytic RNEA derivatives."""
    n = model.n
    q, dq = x[n : 2 * n], x[3 * n :]
    ddq = model.elastic_accelerations(x, tau)[1]
    drnea_dq, drnea_dv, M = model.rnea_derivatives(q, dq, ddq)
    K, D = np.diag(model.K), np.diag(model.D)
    dtau_j = np.hstack([K, -K, D, -D])
    SBinv = model.S * model.B_inv
    dr = -(np.eye(n) + SBinv) @ dtau_j
    dr[:, n : 2 * n] += drnea_dq
    dr[:, 3 * n :] += drnea_dv
    dq_dx = -np.linalg.solve(M - SBinv @ model.S.T, dr)
    return np.vstack([-model.B_inv[:, None] * (dtau_j + model.S.T @ dq_dx), dq_dx])


def pinocchio_accelerometer_jacobians(model: RobotModel, q, dq, ddq):
    """d readings / d(q, q') at fixed q'' from pinocchio's point-acceleration derivatives
    (LOCAL) and the rotation of gravity, -[R^T g]_x J_w."""
    pm, data = model.pin_model, model.data
    pin.computeForwardKinematicsDerivatives(pm, data, q, dq, ddq)
    pin.computeJointJacobians(pm, data, q)
    pin.updateFramePlacements(pm, data)
    d_dq, d_dv = [], []
    for fid in model.sensor_frame_ids:
        frame = pm.frames[fid]
        _, a_dq, a_dv, _ = pin.getPointClassicAccelerationDerivatives(
            pm, data, frame.parentJoint, frame.placement, pin.ReferenceFrame.LOCAL
        )
        j_w = pin.getFrameJacobian(pm, data, fid, pin.ReferenceFrame.LOCAL)[3:]
        gravity_local = data.oMf[fid].rotation.T @ model.gravity_vector
        d_dq.append(a_dq - pin.skew(gravity_local) @ j_w)
        d_dv.append(a_dv)
    return np.vstack(d_dq), np.vstack(d_dv)


def test_batched_jacobians_equal_pinocchio_per_arm(model):
    """F and the accelerometer rows of H of N arms at once (chain kernels, complex step)
    equal pinocchio's analytic derivatives arm by arm to 1e-9, and the batch of one arm
    is the single call."""
    ekf = ExtendedKalmanFilter(model, DT, use_accelerometers=True)
    states = [random_state(model, seed) for seed in range(4)]
    X, T = np.array([s[0] for s in states]), np.array([s[1] for s in states])
    F, G = ekf.linearization(X, T)
    h, H = ekf.measurement_model(X, T)
    n = model.n
    for i, (x, tau) in enumerate(states):
        expected = pinocchio_acceleration_jacobian(model, x, tau)
        assert np.abs(F[i, 2 * n :] - expected).max() < 1e-9 * np.abs(expected).max()
        q, dq = x[n : 2 * n], x[3 * n :]
        ddq = model.elastic_accelerations(x, tau)[1]
        d_dq, d_dv = pinocchio_accelerometer_jacobians(model, q, dq, ddq)
        T_A = model.accelerometer_maps(q, dq)[0]
        H_acc = T_A @ expected[n:]
        H_acc[:, n : 2 * n] += d_dq
        H_acc[:, 3 * n :] += d_dv
        assert np.abs(H[i, n:] - H_acc).max() < 1e-9 * np.abs(H_acc).max()
        single_h, single_H = ekf.measurement_model(x, tau)
        np.testing.assert_array_equal(single_H, H[i])
        np.testing.assert_array_equal(single_h, h[i])
        np.testing.assert_array_equal(ekf.linearization(x, tau)[1], G[i])
