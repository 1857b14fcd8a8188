"""Eq. (13) with integral action: removes the static offset of a wrong gravity model, no harm
on the nominal arm, a stable augmented design, and anti-windup."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from helpers import simulate

from elastic_gym.controllers import make_controller
from elastic_gym.controllers.gain_design import closed_loop_poles, linearize
from elastic_gym.observers import TrueStateWrapper

TWO_LINK = "elastic_gym/TwoLinkElastic-v0"
# one 0.6 s motion after 0.1 s at rest, then 0.8 s at rest at the target
TRACK = {"task": "tracking", "task_options": {"n_moves": 1, "move_time": 0.6, "dwell_time": 0.1}}
STEPS = 1500
LATE = 300  # the last 0.3 s, at rest 0.5 s after the motion ended


def run(controller: str, link_mass: float = 1.0, **options) -> dict:
    env = TrueStateWrapper(gym.make(TWO_LINK, plant_scaling={"link_mass": link_mass}, **TRACK))
    base = env.unwrapped
    law = make_controller(controller, base.model, base.control_dt, **options)
    out = simulate(env, law, STEPS)
    out["link_mass_change"] = law.link_mass_change
    out["late"] = float(np.max(np.linalg.norm(out["error"][-LATE:], axis=1)))
    out["rms"] = float(np.sqrt(np.mean(np.sum(out["error"] ** 2, axis=1))))
    return out


@pytest.fixture(scope="module")
def runs() -> dict:
    return {
        (name, mass): run(name, mass)
        for name in ("feedforward-state-feedback", "integral-state-feedback")
        for mass in (1.0, 1.3)
    }


@pytest.mark.slow
def test_integral_action_removes_the_static_offset_of_heavier_links(runs):
    plain = runs[("feedforward-state-feedback", 1.3)]
    integral = runs[("integral-state-feedback", 1.3)]
    # eq. (13): the feedforward misses 30 % of the gravity torque, the state feedback
    # balances it with a static link offset (measured 7.9e-3 rad)
    assert plain["late"] > 3e-3
    assert np.ptp(plain["error"][-LATE:], axis=0).max() < 0.05 * plain["late"]  # it is static
    # the integrator removes it (measured: below 3.4e-5 rad 0.5 s after the motion, the
    # integral poles are at 11 rad/s) and the whole-run RMS drops 2.9x (1.0e-2 -> 3.6e-3)
    assert integral["late"] < 0.01 * plain["late"]
    assert integral["rms"] < 0.4 * plain["rms"]


@pytest.mark.slow
def test_integral_action_does_no_harm_on_the_nominal_arm(runs):
    plain = runs[("feedforward-state-feedback", 1.0)]
    integral = runs[("integral-state-feedback", 1.0)]
    # measured RMS 1.79e-4 vs 2.00e-4 rad
    assert integral["rms"] < 1.1 * plain["rms"]
    assert integral["late"] < 1e-5 and plain["late"] < 1e-5  # vs 7.9e-3 with heavier links


@pytest.mark.slow
@pytest.mark.parametrize("identification", ["per-link", "shared"])
@pytest.mark.parametrize("controller", ["integral-state-feedback", "feedforward-state-feedback"])
def test_load_identification_finds_the_link_masses_and_tracks_as_on_the_nominal_arm(
    runs, controller, identification
):
    """At the reset the arm rests in the static equilibrium of its real links; the motor
    positions show their load through INVDYN's linear dependence on the link masses, and
    the law on the identified model tracks as the nominal law on the nominal arm, where
    it identifies nothing."""
    nominal = run(controller, 1.0, load_identification=identification)
    np.testing.assert_allclose(nominal["link_mass_change"], 0.0, atol=1e-7)
    plain = runs[(controller, 1.0)]["rms"]
    assert abs(nominal["rms"] - plain) < 1e-3 * plain
    for link_mass in (0.7, 1.3):
        identified = run(controller, link_mass, load_identification=identification)
        np.testing.assert_allclose(identified["link_mass_change"], link_mass - 1, atol=1e-4)
        # measured 1.00-1.02x the nominal arm's RMS; integral action alone is 20x above it
        assert identified["rms"] < 1.05 * plain
        if link_mass == 1.3:
            assert identified["rms"] < 0.1 * runs[("integral-state-feedback", 1.3)]["rms"]


def test_augmented_design_is_stable_and_keeps_the_fast_poles():
    env = gym.make(TWO_LINK)
    model = env.unwrapped.model
    env.close()
    plain = make_controller("feedforward-state-feedback", model, 1e-3)
    integral = make_controller("integral-state-feedback", model, 1e-3)
    poles = integral.design["poles"]
    assert poles.shape == (2 + 8,) and np.all(poles.real < 0)
    # the two integral poles are the slowest, near w / 3 of the rigid-joint rule
    assert np.all(np.abs(poles[:2]) < 0.6 * np.abs(plain.design["poles"][0]))
    # without the integrator the new state gain still stabilizes the arm
    A, Bu = linearize(model, integral.design["configuration"])
    assert np.all(closed_loop_poles(A, Bu, integral.gain).real < 0)
    with pytest.raises(ValueError, match="integral_weight"):
        make_controller("integral-state-feedback", model, 1e-3, integral_weight=-1.0)
    with pytest.raises(ValueError, match="integral_limit"):
        make_controller("integral-state-feedback", model, 1e-3, integral_limit=0.0)


@pytest.mark.slow
def test_anti_windup_freezes_on_saturation_and_bounds_the_integral_torque():
    env = gym.make(TWO_LINK)
    model = env.unwrapped.model
    env.close()
    controller = make_controller("integral-state-feedback", model, 1e-3)
    q_d = np.array([0.3, -0.5])
    reference = {
        "q": q_d,
        "dq": np.zeros(2),
        "ddq": np.zeros(2),
        "d3q": np.zeros(2),
        "d4q": np.zeros(2),
    }
    theta_d = model.static_motor_position(q_d)

    def state(offset: float) -> dict:
        return {"state": np.concatenate([theta_d + offset, q_d + offset, np.zeros(4)])}

    controller.reset(state(0.0), {"time": 0.0, "reference": reference})
    # 0.5 rad off: eq. (13)'s own feedback exceeds the torque limits, so z stays frozen
    for k in range(3):
        tau = controller(state(0.5), {"time": 1e-3 * k, "reference": reference})
    assert np.any(np.abs(tau) > np.asarray(model.spec.torque_limit))
    assert np.all(controller.integral == 0.0)
    # a small persistent offset: z integrates, but |K_I z| never exceeds half the limits
    for k in range(3, 20003):
        tau = controller(state(2e-3), {"time": 1e-3 * k, "reference": reference})
    bound = 0.5 * np.asarray(model.spec.torque_limit)
    integral_torque = controller.integral_gain @ controller.integral
    assert np.all(np.abs(integral_torque) <= bound * (1 + 1e-12))
    assert np.isclose(np.abs(integral_torque).max() / bound[np.argmax(np.abs(integral_torque))], 1)
    # calls at one instant do not integrate twice
    before = controller.integral.copy()
    controller(state(2e-3), {"time": 1e-3 * 20002, "reference": reference})
    np.testing.assert_array_equal(controller.integral, before)
