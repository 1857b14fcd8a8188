"""The compiled RK4 integrator of the arms against an independent integration of the model.

The reference: scipy's DOP853 (rtol 1e-12) of models (1)/(2) written here from pinocchio
alone (``aba`` for model (1) and rigid arms, the block system [[B, S^T], [S, M]] of
model (2) solved whole, not the integrator's Schur complement), restarted at every
control period with the torque held, as the integrator holds it. The loops are closed
by a motor PD with gravity compensation computed from each integration's own state, so
3 s motions stay bounded and both integrations see the same law.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest
from scipy.integrate import solve_ivp

from elastic_gym.envs.plant import PlantArray, default_payload_position, with_payload
from elastic_gym.model import RobotModel
from elastic_gym.model.integrator import ArmIntegrator, Tolerance
from elastic_gym.robots.catalog import get_robot
from elastic_gym.robots.spec import LinkFriction

ELASTIC = ["two_link_elastic", "kr15_elastic", "iiwa_elastic"]
PERIOD = 1e-3  # s, the control period


def integrator(models, tolerance=None, substeps=(1, 256)) -> ArmIntegrator:
    plants = PlantArray(models)
    coupling = (plants.SBinv, plants.schur_inertia, plants.ST) if plants.has_coupling else None
    return ArmIntegrator(
        plants.chain, plants.transmission, coupling, models[0].elastic, tolerance, substeps
    )


def split(x: np.ndarray, n: int) -> list[np.ndarray]:
    """Copies of theta, q, theta', q' (N, n) of states x (N, 4 n)."""
    return [x[:, i * n : (i + 1) * n].copy() for i in range(4)]


def reference_rhs(model: RobotModel, data, x, tau, ext):
    """x' of the model from pinocchio alone (see the module docstring)."""
    n = model.n
    theta, q, dtheta, dq = x[:n], x[n : 2 * n], x[2 * n : 3 * n], x[3 * n :]
    friction = model.link_friction(dq)
    if not model.elastic:
        ddq = pin.aba(model.pin_model, data, q, dq, tau - friction + ext)
        return np.concatenate([dq, dq, ddq, ddq])
    tau_j = model.K * (theta - q) + model.D * (dtheta - dq)
    if not model.has_coupling:
        ddq = pin.aba(model.pin_model, data, q, dq, tau_j - friction + ext)
        return np.concatenate([dtheta, dq, (tau - tau_j) / model.B, ddq])
    M = pin.crba(model.pin_model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    nle = pin.nonLinearEffects(model.pin_model, data, q, dq)
    inertia = np.block([[np.diag(model.B), model.S.T], [model.S, M]])
    acc = np.linalg.solve(inertia, np.concatenate([tau - tau_j, tau_j - friction + ext - nle]))
    return np.concatenate([dtheta, dq, acc])


def reference_period(model, data, x, tau, ext, period=PERIOD):
    sol = solve_ivp(
        lambda t, y: reference_rhs(model, data, y, tau, ext),
        (0.0, period),
        x,
        method="DOP853",
        rtol=1e-12,
        atol=1e-14,
    )
    assert sol.success
    return sol.y[:, -1]


class MotorPD:
    """tau = g(q_d) + K_P (theta_d - theta) - K_D theta' along a smooth q_d(t) (rigid arms:
    the same law on q), theta_d = q_d + K^-1 g(q_d): the motor PD with gravity
    compensation of an elastic arm (Tomei 1991)."""

    def __init__(self, model: RobotModel, motion: float = 0.25, rest_after: float = np.inf):
        spec, self.model = model.spec, model
        low, high = np.asarray(spec.workspace_low), np.asarray(spec.workspace_high)
        self.middle, self.amplitude = 0.5 * (low + high), motion * (high - low)
        self.rest_after = rest_after
        B = model.B if model.elastic else np.diag(model.mass_matrix(self.middle))
        self.kp = model.K if model.elastic else 400.0 * B
        self.kd = np.sqrt(self.kp * B)

    def reference(self, t: float) -> np.ndarray:
        s = min(t, self.rest_after)
        return self.middle + 0.5 * self.amplitude * np.sin(np.pi * s + np.arange(self.model.n))

    def initial_state(self) -> np.ndarray:
        q = self.reference(0.0)
        theta = self.model.static_motor_position(q) if self.model.elastic else q
        return np.concatenate([theta, q, np.zeros(2 * self.model.n)])

    def __call__(self, t: float, x: np.ndarray) -> np.ndarray:
        n, model = self.model.n, self.model
        q_d = self.reference(t)
        gravity = model.gravity(q_d)
        if not model.elastic:
            return gravity + self.kp * (q_d - x[n : 2 * n]) - self.kd * x[3 * n :]
        theta_d = q_d + gravity / model.K
        return gravity + self.kp * (theta_d - x[:n]) - self.kd * x[2 * n : 3 * n]


def closed_loops(models, controllers, duration, tolerance=None, pulses=None):
    """Run the arms' closed loops with the integrator (one batch) and with the reference
    (one arm at a time): the two state histories (steps + 1, N, 4 n) and each arm's mean
    substep count (N,)."""
    N, n = len(models), models[0].n
    steps = round(duration / PERIOD)
    integ = integrator(models, tolerance)
    x0 = np.array([c.initial_state() for c in controllers])
    theta, q, dtheta, dq = split(x0, n)
    ours, work = [x0], np.zeros(N)
    for s in range(steps):
        tau = np.array([c(s * PERIOD, x) for c, x in zip(controllers, ours[-1], strict=True)])
        ext = None if pulses is None else pulses(s * PERIOD)
        work += integ.substeps_now  # the substeps of this period unless one is rejected
        integ.step(theta, dtheta, q, dq, tau, PERIOD, ext)
        ours.append(np.concatenate([theta, q, dtheta, dq], axis=1))
    reference = [x0]
    datas = [m.pin_model.createData() for m in models]
    for s in range(steps):
        ext = np.zeros((N, n)) if pulses is None else pulses(s * PERIOD)
        reference.append(
            np.array(
                [
                    reference_period(m, d, x, c(s * PERIOD, x), e)
                    for m, d, c, x, e in zip(
                        models, datas, controllers, reference[-1], ext, strict=True
                    )
                ]
            )
        )
    return np.array(ours), np.array(reference), work / steps


# ------------------------------------------------------------------ the right-hand side
@pytest.mark.parametrize("robot", [*ELASTIC, "two_link_rigid", "two_link_friction"])
def test_derivative_equals_the_model_of_pinocchio(robot):
    """Three arms (nominal, scaled with friction, with a payload), random states, motor and
    link torques: x' equals the independent block formulation to rounding."""
    spec = get_robot(robot)
    n = spec.n_joints
    nominal = RobotModel(spec)
    friction = LinkFriction(viscous=(0.4,) * n, coulomb_pos=(3.0,) * n, coulomb_neg=(2.0,) * n)
    scaled = RobotModel(spec, {"link_mass": 1.3}, added_friction=friction)
    loaded = with_payload(nominal, 2.0, default_payload_position(nominal))
    models = [nominal, scaled, loaded]
    integ = integrator(models)
    rng = np.random.default_rng(4)
    q = rng.uniform(spec.workspace_low, spec.workspace_high, (3, n))
    dq = rng.standard_normal((3, n))
    theta = q + 0.01 * rng.standard_normal((3, n)) if spec.elastic else q.copy()
    dtheta = rng.standard_normal((3, n)) if spec.elastic else dq.copy()
    tau = 0.05 * np.asarray(spec.torque_limit) * rng.uniform(-1.0, 1.0, (3, n))
    ext = 0.02 * np.asarray(spec.torque_limit) * rng.uniform(-1.0, 1.0, (3, n))
    ours = integ.derivative(theta, dtheta, q, dq, tau, ext)
    for k, model in enumerate(models):
        x = np.concatenate([theta[k], q[k], dtheta[k], dq[k]])
        expected = reference_rhs(model, model.pin_model.createData(), x, tau[k], ext[k])
        np.testing.assert_allclose(ours[k], expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    # the friction, the payload and the link torque each change q''
    bare = integ.derivative(theta, dtheta, q, dq, tau)
    assert np.abs(bare - ours).max() > 1e-3


# ------------------------------------------------------------------ convergence
@pytest.mark.slow
@pytest.mark.parametrize("robot", ELASTIC)
def test_three_second_motions_match_dop853_within_1e_6_rad(robot):
    """3 s closed-loop motions at the 1 ms control period: link positions within 1e-6 rad of
    DOP853 (rtol 1e-12) with the default tolerances, in about one substep per period."""
    model = RobotModel(get_robot(robot))
    controller = MotorPD(model)
    ours, reference, substeps = closed_loops([model], [controller], 3.0)
    n = model.n
    assert np.ptp(reference[:, 0, n : 2 * n], axis=0).max() > 0.5  # rad: a real motion
    assert np.abs(ours - reference)[:, 0, n : 2 * n].max() < 1e-6
    assert np.abs(ours - reference)[:, 0, 3 * n :].max() < 1e-4  # rad/s
    assert substeps[0] < 1.5  # the control period itself is (nearly always) the step


@pytest.mark.slow
def test_plant_features_match_dop853():
    """Per-arm plants in one batch: Coulomb friction of 5 % of the torque limits (its tanh
    resolved by the step-size control, which takes more substeps), a payload and scaled
    links, under link torque pulses held over control periods."""
    spec = get_robot("two_link_elastic")
    limit = np.asarray(spec.torque_limit)
    coulomb = LinkFriction(viscous=(0.0, 0.0), coulomb_pos=tuple(0.05 * limit))
    nominal = RobotModel(spec)
    models = [
        nominal,
        RobotModel(spec, added_friction=coulomb),
        with_payload(RobotModel(spec, {"link_mass": 1.2}), 1.0, default_payload_position(nominal)),
    ]
    controllers = [MotorPD(m, motion=0.1, rest_after=0.5) for m in models]

    def pulses(t):
        on = 0.2 <= t < 0.23 or 0.7 <= t < 0.71
        return np.tile(0.05 * limit * np.array([1.0, -1.0]), (3, 1)) * on

    ours, reference, substeps = closed_loops(models, controllers, 1.0, pulses=pulses)
    n = spec.n_joints
    error = np.abs(ours - reference)[:, :, n : 2 * n].max(axis=(0, 2))
    assert error.max() < 1e-6, error
    # the friction arm's steep tanh near q' = 0 takes more substeps
    assert substeps[1] > 1.2 * substeps[0], substeps


@pytest.mark.parametrize("robot", ELASTIC)
def test_fourth_order_in_the_step(robot):
    """Fixed substeps (no step-size control) from a state off equilibrium: the error after
    0.1 s falls 16-fold per halving of the step (RK4's order 4)."""
    model = RobotModel(get_robot(robot))
    controller = MotorPD(model)
    x0 = controller.initial_state()
    n = model.n
    x0[:n] += 0.002  # a torsion oscillation at every natural frequency
    data = model.pin_model.createData()
    steps = 100
    reference, torques = x0, []
    for s in range(steps):
        torques.append(controller(s * PERIOD, reference))
        reference = reference_period(model, data, reference, torques[-1], np.zeros(n))
    errors = []
    for m in (2, 4, 8):
        integ = integrator([model], Tolerance(1e9, 1e9), substeps=(m, m))
        x = x0[None]
        theta, q, dtheta, dq = split(x, n)
        for tau in torques:
            assert integ.step(theta, dtheta, q, dq, tau[None], PERIOD) == m
        errors.append(np.abs(np.concatenate([theta, q, dtheta, dq], axis=1)[0] - reference).max())
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all((ratios > 12.0) & (ratios < 20.0)), (errors, ratios)


# ------------------------------------------------------------------ invariants
@pytest.mark.slow
@pytest.mark.parametrize("robot", ELASTIC)
def test_energy_drift_without_torque_and_damping(robot):
    """Zero motor torque, D = 0, no friction (iiwa: no gravity, a free fall would cross its
    joint limits): over 3 s the total energy stays within 1e-6 of the energy in play."""
    base = get_robot(robot)
    changes: dict = {"damping": (0.0,) * base.n_joints}
    if robot == "iiwa_elastic":
        changes["gravity"] = (0.0, 0.0, 0.0)
    spec = dataclasses.replace(base, **changes)
    model = RobotModel(spec)
    n = model.n
    rng = np.random.default_rng(1)
    q = 0.5 * (np.asarray(spec.workspace_low) + np.asarray(spec.workspace_high))
    x = [model.static_motor_position(q) + 0.01 * rng.standard_normal(n), q, np.zeros(n)]
    x.append(0.5 * rng.standard_normal(n))
    theta, q, dtheta, dq = (np.ascontiguousarray(v[None]) for v in x)
    integ = integrator([model])
    zero = np.zeros((1, n))
    energy, in_play = [], []
    for _ in range(3000):
        energy.append(model.energy(q[0], dq[0], theta[0], dtheta[0]))
        delta = theta[0] - q[0]
        kinetic = 0.5 * dq[0] @ model.mass_matrix(q[0]) @ dq[0] + 0.5 * dtheta[0] @ (
            model.B * dtheta[0]
        )
        in_play.append(kinetic + 0.5 * delta @ (model.K * delta))
        integ.step(theta, dtheta, q, dq, zero, PERIOD)
    energy, scale = np.array(energy), max(in_play)
    assert scale > 0.01
    assert np.abs(energy - energy[0]).max() / scale < 1e-6


@pytest.mark.parametrize("robot", ELASTIC)
def test_accelerometer_readings_equal_the_second_difference_of_the_sensor_point(robot):
    """The readings of eq. (9) from the integrated state and its q'' (the end of each
    period) against R_WS^T (a - g_W) with a the second difference of the sensor point's
    world position over the integrated positions (25 us periods: the difference's error
    (omega dt)^2 / 12 is 1e-5 of the iiwa wrist's torsion mode)."""
    model = RobotModel(get_robot(robot))
    controller = MotorPD(model)
    n, dt = model.n, 2.5e-5
    x0 = controller.initial_state()
    x0[:n] += 0.002
    theta, q, dtheta, dq = split(x0[None], n)
    integ = integrator([model])
    ddq = np.empty((1, n))
    points, readings = [], []
    for s in range(800):
        x = np.concatenate([theta[0], q[0], dtheta[0], dq[0]])
        integ.step(theta, dtheta, q, dq, controller(s * dt, x)[None], dt, ddq=ddq)
        placements = model.sensor_placements(q[0])
        points.append([p.translation.copy() for p in placements])
        rotations = [p.rotation.copy() for p in placements]
        readings.append((model.chain.specific_forces(q, dq, ddq)[0], rotations))
    points = np.array(points)  # (steps, sensors, 3)
    worst, scale = 0.0, 0.0
    for s in range(1, len(points) - 1):
        a = (points[s + 1] - 2.0 * points[s] + points[s - 1]) / dt**2
        f, rotations = readings[s]
        for i, R in enumerate(rotations):
            expected = R.T @ (a[i] - model.gravity_vector)
            worst = max(worst, np.abs(f[3 * i : 3 * i + 3] - expected).max())
            scale = max(scale, np.abs(a[i]).max())
    assert scale > 0.1  # m/s^2 of dynamic acceleration
    assert worst < 1e-4 * scale, (worst, scale)


def test_arm_of_a_batch_is_bit_for_bit_the_arm_alone():
    """Per-arm plants and step-size control: each arm's substeps are its own."""
    spec = get_robot("kr15_elastic")
    limit = np.asarray(spec.torque_limit)
    models = [
        RobotModel(spec),
        RobotModel(
            spec, {"stiffness": 0.9}, added_friction=LinkFriction((0.0,) * 3, tuple(0.03 * limit))
        ),
        RobotModel(spec, {"link_mass": 1.2}),
    ]
    controllers = [MotorPD(m, motion=0.1) for m in models]
    n = spec.n_joints
    runs = []
    for arms in ([0, 1, 2], [0], [1], [2]):
        integ = integrator([models[k] for k in arms])
        x = np.array([controllers[k].initial_state() for k in arms])
        theta, q, dtheta, dq = split(x, n)
        states = []
        for s in range(100):
            x = np.concatenate([theta, q, dtheta, dq], axis=1)
            tau = np.array([controllers[k](s * PERIOD, xk) for k, xk in zip(arms, x, strict=True)])
            integ.step(theta, dtheta, q, dq, tau, PERIOD)
            states.append(np.concatenate([theta, q, dtheta, dq], axis=1))
        runs.append(np.array(states))
    for k in range(3):
        assert np.array_equal(runs[0][:, k], runs[k + 1][:, 0])


def test_bad_settings_are_refused():
    model = RobotModel(get_robot("two_link_elastic"))
    with pytest.raises(ValueError, match="tolerances must be > 0"):
        integrator([model], Tolerance(0.0, 1e-6))
    with pytest.raises(ValueError, match="substeps"):
        integrator([model], substeps=(4, 2))
    integ = integrator([model])
    state = [np.zeros((1, 2)) for _ in range(4)]
    with pytest.raises(ValueError, match="shape"):
        integ.step(*state, np.zeros((2, 2)), PERIOD)
    with pytest.raises(ValueError, match="period"):
        integ.step(*state, np.zeros((1, 2)), 0.0)
