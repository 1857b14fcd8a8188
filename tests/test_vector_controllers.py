"""Vector controllers: each arm's torque equals the single controller's (1e-12) over real
closed-loop trajectories of a vector env (arms with their own seeds, so their own states and
references, through an autoreset); INVDYN's batched RNEA tangents equal pinocchio's."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from helpers import N_ARMS, closed_loop_gap, fast_lane, relative_gap

from elastic_gym.controllers import Controller, make_controller
from elastic_gym.controllers.invdyn import RigidTorque
from elastic_gym.controllers.vector import (
    ControllerArray,
    ControllerTwin,
    make_vector_controller,
)
from elastic_gym.model import RobotModel
from elastic_gym.robots.catalog import ROBOTS, get_robot

TWO_LINK, KR15, IIWA = (
    f"elastic_gym/{n}-v0" for n in ("TwoLinkElastic", "KR15Elastic", "IiwaElastic")
)
RIGID, FRICTION = "elastic_gym/TwoLinkRigid-v0", "elastic_gym/TwoLinkRigidFriction-v0"


def _tanh_policy(obs) -> np.ndarray:
    x = np.asarray(obs["state"])
    return np.tanh(x[:2] - x[2:4] + 0.1 * x[-2:])


CASES = [
    (TWO_LINK, "feedforward-state-feedback", {}),
    (KR15, "feedforward-state-feedback", {}),
    (IIWA, "feedforward-state-feedback", {}),
    (RIGID, "feedforward-state-feedback", {}),
    (TWO_LINK, "feedforward-state-feedback", {"feedforward": False}),
    (TWO_LINK, "integral-state-feedback", {}),
    (KR15, "integral-state-feedback", {}),
    (KR15, "integral-state-feedback", {"load_identification": "per-link"}),
    (TWO_LINK, "motor-pd", {"load_identification": "shared"}),
    (TWO_LINK, "motor-pd", {}),
    (KR15, "motor-pd", {"feedforward": False}),
    (TWO_LINK, "link-pd", {}),
    (RIGID, "link-pd", {}),
    (RIGID, "cristofaro-tracking", {}),
    (RIGID, "feedback-linearization", {}),
    (FRICTION, "feedback-linearization", {"friction_velocity": "desired"}),
    (
        TWO_LINK,
        "policy",
        {"policy": _tanh_policy, "residual": "integral-state-feedback", "decimation": 3},
    ),
    (RIGID, "policy", {"policy": _tanh_policy, "decimation": 2}),
]


@pytest.mark.parametrize(
    ("env_id", "name", "options"),
    fast_lane(CASES, CASES[1], CASES[7], CASES[13], CASES[16]),  # KR15, integral, rigid, policy
)
def test_each_arm_torque_equals_the_single_controller(env_id, name, options):
    model = gym.make(env_id).unwrapped.model
    batched = make_vector_controller(name, model, 1e-3, N_ARMS, **options)
    assert isinstance(batched, ControllerTwin)  # a built-in: its batched twin
    singles = [make_controller(name, model, 1e-3, **options) for _ in range(N_ARMS)]
    assert closed_loop_gap(env_id, batched, singles) < 1e-12


class _UserController(Controller):
    """A user's controller with memory: PD on the link plus a counter."""

    def reset(self, obs, info) -> None:
        self.calls = 0

    def __call__(self, obs, info) -> np.ndarray:
        self.calls += 1
        x, q_d = obs["state"], info["reference"]["q"]
        return 200.0 * (q_d - x[2:4]) - 20.0 * x[6:8] + 1e-3 * self.calls


def test_a_user_controller_runs_one_copy_per_arm():
    model = gym.make(TWO_LINK).unwrapped.model
    batched = make_vector_controller(_UserController, model, 1e-3, N_ARMS)
    assert isinstance(batched, ControllerArray) and len(batched.controllers) == N_ARMS
    singles = [_UserController(model, 1e-3) for _ in range(N_ARMS)]
    assert closed_loop_gap(TWO_LINK, batched, singles) == 0.0


def test_a_subclass_of_a_built_in_is_not_replaced_by_the_built_in_twin():
    from elastic_gym.controllers.state_feedback import FeedforwardStateFeedback

    class Doubled(FeedforwardStateFeedback):
        def __call__(self, obs, info):
            return 2.0 * super().__call__(obs, info)

    model = gym.make(TWO_LINK).unwrapped.model
    batched = make_vector_controller(Doubled, model, 1e-3, N_ARMS)
    assert isinstance(batched, ControllerArray)
    singles = [Doubled(model, 1e-3) for _ in range(N_ARMS)]
    assert closed_loop_gap(TWO_LINK, batched, singles) == 0.0


def test_bad_vector_controller_input_is_refused():
    model = gym.make(TWO_LINK).unwrapped.model
    with pytest.raises(ValueError, match="n_arms must be an integer >= 1"):
        make_vector_controller("motor-pd", model, 1e-3, 0)
    with pytest.raises(ValueError, match="unknown controller"):
        make_vector_controller("nope", model, 1e-3, 2)
    with pytest.raises(TypeError, match="registry name, a Controller class or instance"):
        make_vector_controller(dict, model, 1e-3, 2)
    with pytest.raises(ValueError, match="fd_step"):  # options are checked by the design
        make_vector_controller("feedforward-state-feedback", model, 1e-3, 2, fd_step=-1.0)
    controller = make_vector_controller("feedforward-state-feedback", model, 1e-3, 2)
    reference = {k: np.zeros((2, 2)) for k in ("q", "dq", "ddq", "d3q", "d4q")}
    with pytest.raises(ValueError, match=r"obs\['state'\] must have shape \(2, 8\)"):
        controller({"state": np.zeros(8)}, {"time": np.zeros(2), "reference": reference})
    with pytest.raises(
        ValueError, match=r"info\['time'\] must have finite entries and shape \(2,\)"
    ):
        controller({"state": np.zeros((2, 8))}, {"time": 0.0, "reference": reference})


@pytest.mark.parametrize("robot", [name for name in ROBOTS])
def test_batched_rigid_torque_and_its_derivatives_equal_pinocchio(robot):
    """tau_r and tau_r' of N arms by the chain kernels (complex-step RNEA tangent) equal
    pinocchio's RNEA and analytic RNEA derivatives to 1e-13; tau_r'' equals the central
    difference of pinocchio's exact tau_r'."""
    model = RobotModel(get_robot(robot))
    rng = np.random.default_rng(3)
    ref = rng.normal(size=(6, 5, model.n))
    rt = RigidTorque(model)
    tau, dtau, ddtau = rt.derivatives(ref)
    for k, r in enumerate(ref):
        q, dq, ddq, d3q = r[:4]
        expected = model.rnea(q, dq, ddq) + model.link_friction(dq)
        dq_, dv_, M = model.rnea_derivatives(q, dq, ddq)
        slope = dq_ @ dq + dv_ @ ddq + M @ d3q
        if model.friction is not None:
            slope = slope + model.friction.derivative(dq) * ddq

        def pin_slope(s):
            d_q, d_v, M_ = model.rnea_derivatives(s[0], s[1], s[2])
            out = d_q @ s[1] + d_v @ s[2] + M_ @ s[3]
            return out + (0.0 if model.friction is None else model.friction.derivative(s[1]) * s[2])

        central = (pin_slope(rt._ahead @ r) - pin_slope(rt._behind @ r)) / (2.0 * rt.fd_step)
        assert relative_gap(tau[k], expected) < 1e-13
        assert relative_gap(dtau[k], slope) < 1e-13
        assert relative_gap(ddtau[k], central) < 1e-9  # a difference quotient: rounding / 2h


@pytest.mark.slow
@pytest.mark.usefixtures("single_thread_torch")
def test_trained_policy_arms_equal_the_single_controller(tmp_path):
    """A residual run on eq. (13) (tiny SAC run, on the true state): each arm of its vector
    twin (features of all arms at once, the base eq. (13) batched) gets the single
    controller's torque."""
    from elastic_gym.training import TrainConfig, train

    config = TrainConfig(
        algo="sac",
        state="true",
        total_steps=100,
        out_dir=str(tmp_path / "run"),
        env_kwargs={"max_episode_steps": 200},
        eval_freq=10**9,
        action={"kind": "residual", "residual": "feedforward-state-feedback"},
        hyperparams={"learning_starts": 50, "batch_size": 32, "policy_kwargs": {"net_arch": [8]}},
    )
    train(config, progress_bar=False)
    model = gym.make(TWO_LINK).unwrapped.model
    options = {"run": config.out_dir, "trust_pickle": True}
    batched = make_vector_controller("trained-policy", model, 1e-3, N_ARMS, **options)
    assert isinstance(batched, ControllerTwin)
    singles = [make_controller("trained-policy", model, 1e-3, **options) for _ in range(N_ARMS)]
    assert closed_loop_gap(TWO_LINK, batched, singles) < 1e-12
