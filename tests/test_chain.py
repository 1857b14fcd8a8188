"""The batched serial chain equals pinocchio, and each arm's result does not depend on N."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from elastic_gym.model import RobotModel
from elastic_gym.robots.catalog import ROBOTS, get_robot


def _states(model: RobotModel, n_arms: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    spec = model.spec
    q = rng.uniform(spec.workspace_low, spec.workspace_high, (n_arms, model.n))
    dq, ddq, tau = (3.0 * rng.standard_normal((n_arms, model.n)) for _ in range(3))
    return q, dq, ddq, tau


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


@pytest.mark.parametrize("robot", list(ROBOTS))
def test_chain_equals_pinocchio(robot):
    """M, n(q, q'), forward dynamics (with the model-(2) Schur inertia), accelerometer
    readings and the maps T_A, W_A of eq. (10), on a scaled model, at random states."""
    model = RobotModel(get_robot(robot), {"link_mass": 1.3, "link_inertia": 0.7})
    chain = model.chain
    q, dq, ddq, tau = _states(model, 6)
    M, h = chain.mass_and_bias(q, dq)
    added = -0.01 * np.eye(model.n) if model.elastic else None
    ddq_chain = chain.forward_dynamics(q, dq, tau, added)
    worst = 0.0
    for k in range(len(q)):
        M_ref = model.mass_matrix(q[k])
        worst = max(worst, _relative(M[k], M_ref))
        worst = max(worst, _relative(h[k], model.nonlinear_effects(q[k], dq[k])))
        M_total = M_ref + (added if added is not None else 0.0)
        expected = np.linalg.solve(M_total, tau[k] - model.nonlinear_effects(q[k], dq[k]))
        worst = max(worst, _relative(ddq_chain[k], expected))
        worst = max(worst, _relative(chain.gravity(q[k : k + 1])[0], model.gravity(q[k])))
    if model.n_sensors:
        readings = chain.specific_forces(q, dq, ddq)
        T, W = chain.accelerometer_maps(q, dq)
        for k in range(len(q)):
            worst = max(
                worst, _relative(readings[k], model.accelerometer_readings(q[k], dq[k], ddq[k]))
            )
            T_ref, W_ref = model.accelerometer_maps(q[k], dq[k])
            worst = max(worst, _relative(T[k], T_ref), _relative(W[k], W_ref))
            assert np.allclose(T[k] @ ddq[k] + W[k], readings[k], rtol=1e-12, atol=1e-12)
    assert worst < 1e-12


@pytest.mark.parametrize("robot", ["two_link_elastic", "kr15_elastic", "iiwa_elastic"])
def test_each_arm_is_bit_identical_whatever_the_batch_size(robot):
    model = RobotModel(get_robot(robot))
    chain = model.chain
    q, dq, ddq, tau = _states(model, 64, seed=3)
    batch = [
        chain.forward_dynamics(q, dq, tau),
        chain.specific_forces(q, dq, ddq),
        *chain.accelerometer_maps(q, dq),
        *chain.mass_and_bias(q, dq),
    ]
    for k in (0, 17, 63):
        rows = slice(k, k + 1)
        alone = [
            chain.forward_dynamics(q[rows], dq[rows], tau[rows]),
            chain.specific_forces(q[rows], dq[rows], ddq[rows]),
            *chain.accelerometer_maps(q[rows], dq[rows]),
            *chain.mass_and_bias(q[rows], dq[rows]),
        ]
        for whole, single in zip(batch, alone, strict=True):
            assert np.array_equal(whole[k], single[0])


def test_chain_checks_shapes_and_pickles():
    model = RobotModel(get_robot("two_link_elastic"))
    chain = model.chain
    with pytest.raises(ValueError, match=r"shape \(N, 2\)"):
        chain.forward_dynamics(np.zeros(2), np.zeros(2), np.zeros(2))
    q, dq, ddq, _ = _states(model, 3)
    copy = pickle.loads(pickle.dumps(chain))
    assert np.array_equal(copy.specific_forces(q, dq, ddq), chain.specific_forces(q, dq, ddq))


@pytest.mark.parametrize("robot", list(ROBOTS))
def test_dynamics_and_forces_in_one_call_equal_the_two_calls(robot):
    """The fused kernel of the env step is forward dynamics then eq. (9), bit for bit."""
    model = RobotModel(get_robot(robot))
    chain = model.chain
    for n_arms in (1, 5):
        q, dq, _, tau = _states(model, n_arms, seed=4)
        ddq, forces = chain.forward_dynamics_and_forces(q, dq, tau)
        expected = chain.forward_dynamics(q, dq, tau)
        assert np.array_equal(ddq, expected)
        assert np.array_equal(forces, chain.specific_forces(q, dq, expected))


def test_thin_svd_of_the_accelerometer_maps_is_lapacks():
    """`thin_svd` (LAPACK's dgesdd with a reused workspace) gives the thin SVD of a 6 x 2
    map, as numpy's SVD does, and a second call overwrites the first's views."""
    from elastic_gym.model.lapack import svd_workspace, thin_svd

    rng = np.random.default_rng(0)
    space = svd_workspace(6, 2)
    for _ in range(2):
        T = rng.normal(size=(6, 2))
        u, s, vt = thin_svd(T, space)
        U, V_T = u.T, vt.T  # (6, 2) and (2, 2)
        np.testing.assert_allclose(U @ np.diag(s) @ V_T, T, rtol=0, atol=1e-13)
        np.testing.assert_allclose(U.T @ U, np.eye(2), rtol=0, atol=1e-14)
        np.testing.assert_allclose(V_T @ V_T.T, np.eye(2), rtol=0, atol=1e-14)
        np.testing.assert_allclose(s, np.linalg.svd(T, compute_uv=False), rtol=1e-14)


def test_thin_svd_of_two_columns_is_dgesdd_bit_for_bit():
    """The two-column path of `thin_svd` (dgesdd's own routines, without its queries) gives
    dgesdd's U, s and V^T to the last bit: random, rank-deficient, zero and badly scaled
    m x 2 maps (those dgesdd scales go to dgesdd itself), m = 3, 6, 9."""
    from elastic_gym.model.lapack import lapack_svd, svd_workspace, thin_svd

    rng = np.random.default_rng(1)
    for m in (3, 6, 9):
        space, reference = svd_workspace(m, 2), svd_workspace(m, 2)
        for trial in range(300):
            T = rng.normal(size=(m, 2)) * 10.0 ** rng.uniform(-140, 140)
            if trial % 3 == 0:  # nearly parallel columns: sigma_min ~ 1e-9 sigma_max
                T[:, 1] = 0.5 * T[:, 0] + 1e-9 * rng.normal(size=m)
            if trial % 5 == 1:
                T[:, trial % 2] = 0.0
            if trial % 7 == 2:
                T[:] = 0.0
            got = [x.copy() for x in thin_svd(T, space)]
            for g, e in zip(got, lapack_svd(T, reference), strict=True):
                assert np.array_equal(g, e), (m, trial)
    with pytest.raises(ValueError, match="failed to converge"):  # as dgesdd: NaN refused
        thin_svd(np.full((6, 2), np.nan), svd_workspace(6, 2))
