"""One name per concept: the controller registry takes names from packages above it
without importing upward, the joint kind and the arm-axis helpers exist once."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from elastic_gym.arms import REFERENCE_KEYS, arm_view, reference_rows
from elastic_gym.controllers import CONTROLLERS, register_controller
from elastic_gym.robots.catalog import ROBOTS, get_robot


@pytest.mark.slow
def test_comparison_imports_the_policy_package_only_when_a_policy_is_named():
    """... never the training stack (an exported policy needs none), and matplotlib only
    to plot: a comparison's workers import the package."""
    code = (
        "import sys\n"
        "import elastic_gym.cli, elastic_gym.controllers, elastic_gym.evaluation\n"
        "assert not [m for m in sys.modules if m.startswith('elastic_gym.training')]\n"
        "assert not [m for m in sys.modules if m.startswith('elastic_gym.policy')]\n"
        "assert 'matplotlib' not in sys.modules\n"
        "from elastic_gym.evaluation.controllers import comparison_controller, controller_names\n"
        "assert {'policy', 'trained-policy'} <= set(controller_names())\n"
        "assert comparison_controller('motor-pd').__name__ == 'MotorPD'\n"
        "assert 'elastic_gym.policy.controller' not in sys.modules\n"
        "cls = comparison_controller('trained-policy')\n"
        "assert cls is comparison_controller('policy'), cls\n"
        "assert cls.__name__ == 'PolicyController', cls\n"
        "assert 'elastic_gym.policy.controller' in sys.modules\n"
        "assert not [m for m in sys.modules if m.startswith('elastic_gym.training')]\n"
        "assert 'torch' not in sys.modules and 'stable_baselines3' not in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_register_controller_refuses_a_taken_name_and_a_bad_target():
    before = dict(CONTROLLERS)
    target = "elastic_gym.policy.controller:PolicyController"
    register_controller("trained-policy", target)  # the same target again: nothing changes
    assert before == CONTROLLERS
    with pytest.raises(ValueError, match=r"'motor-pd' is taken by elastic_gym\.controllers\.pd"):
        register_controller("motor-pd", target)
    with pytest.raises(ValueError, match="must be 'module:Class'"):
        register_controller("mine", "elastic_gym.controllers.pd.MotorPD")
    assert before == CONTROLLERS


def test_robot_kind_names_the_joints():
    for name in ROBOTS:
        spec = get_robot(name)
        assert spec.kind == ("elastic" if spec.elastic else "rigid")
    assert {get_robot(name).kind for name in ROBOTS} == {"elastic", "rigid"}


def test_reference_rows_of_a_batch_are_the_rows_of_its_arms():
    rng = np.random.default_rng(0)
    batched = {"reference": {key: rng.normal(size=(3, 2)) for key in REFERENCE_KEYS}}
    batched["_reference"] = np.ones(3, dtype=bool)
    rows = reference_rows(batched)
    assert rows.shape == (3, 5, 2)
    for i in range(3):
        arm = arm_view(batched, i)
        assert set(arm) == {"reference"}
        np.testing.assert_array_equal(reference_rows(arm), rows[i])
        for k, key in enumerate(REFERENCE_KEYS):
            np.testing.assert_array_equal(rows[i, k], batched["reference"][key][i])


def test_residual_means_one_thing_for_the_policy_controller_and_the_action_map():
    """The callable-level PolicyController and the training's residual action give the
    same torque bit for bit on the same base torque, deadzone (default) included."""
    import gymnasium as gym

    from elastic_gym.controllers import make_controller, public_info
    from elastic_gym.observers import TrueStateWrapper
    from elastic_gym.policy import ActionConfig, ActionMap
    from elastic_gym.policy.actions import RESIDUAL_DEADZONE
    from elastic_gym.policy.controller import PolicyController

    env = TrueStateWrapper(gym.make("elastic_gym/TwoLinkElastic-v0"))
    obs, info = env.reset(seed=4)
    obs, *_, info = env.step(np.array([0.3, -0.2]))
    info = public_info(info)
    model = env.unwrapped.model
    config = ActionConfig(kind="residual", residual="motor-pd", residual_scale=0.3)
    assert config.residual_deadzone == RESIDUAL_DEADZONE > 0
    action_map = ActionMap(config, model)
    base = make_controller("motor-pd", model, 1e-3)
    base.reset(obs, info)
    actions = np.array([[0.1, -0.15], [0.2, -0.2], [0.5, -0.7], [1.0, -1.0], [1.7, -3.0]])
    for a in actions:
        policy = PolicyController(
            model, 1e-3, lambda o, a=a: a, residual="motor-pd", residual_scale=0.3
        )
        policy.reset(obs, info)
        expected = action_map.torque(a[None], base_torque=base(obs, info)[None])[0]
        np.testing.assert_array_equal(policy(obs, info), expected)
    inside = PolicyController(model, 1e-3, lambda o: actions[0], residual="motor-pd")
    inside.reset(obs, info)
    np.testing.assert_array_equal(inside(obs, info), base(obs, info))  # |a| <= d: no residual
    for deadzone in (1.0, -0.1, "0.2"):
        with pytest.raises((ValueError, TypeError), match=r"^options\.residual_deadzone: "):
            PolicyController(model, 1e-3, abs, residual="motor-pd", residual_deadzone=deadzone)
    env.close()
