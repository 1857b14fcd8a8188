"""Policies trained on raw sensors in the comparison and the benchmark, and the policy
evaluation (evaluate_run, the learning curve) on the comparison's loop."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml
from helpers import spec_env

from elastic_gym.benchmark import load_suite, run_benchmark
from elastic_gym.benchmark.scorecard import scorecard_markdown
from elastic_gym.cli.compare import with_trained_policy
from elastic_gym.evaluation import plan_runs
from elastic_gym.evaluation.closed_loop import ClosedLoop
from elastic_gym.evaluation.episodes import run_group
from elastic_gym.evaluation.execute import execute
from elastic_gym.evaluation.groups import RunGroup
from elastic_gym.evaluation.scenario import Scenario, ScenarioError, SourceEntry
from elastic_gym.evaluation.world import build_world
from elastic_gym.observers.registry import source_class
from elastic_gym.policy.actors import Actor
from elastic_gym.policy.controller import PolicyController
from elastic_gym.training import TrainConfig, evaluate_run, load_run, train
from elastic_gym.training.trained import evaluation_runs

ENV_ID = "elastic_gym/TwoLinkElastic-v0"
EPISODE = {"episode_time": 0.3}
TINY_NETS = {"batches": 1, "n_steps": 16, "batch_size": 32, "n_epochs": 1}  # one world, here

pytestmark = pytest.mark.usefixtures("single_thread_torch")


@pytest.fixture(scope="module")
def sensor_runs(tmp_path_factory):
    """Three tiny runs on raw sensors: RecurrentPPO (an LSTM, one frame), PPO on a stack
    of three frames, and a RecurrentPPO policy distilled from the plant teacher that sees
    the motor error at the reset; all with the default motor-offset action (the encoders'
    backward difference in its D term)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("sensor-runs")
    common = {"state": "sensors", "env_kwargs": EPISODE, "eval_freq": 10**9, "eval_episodes": 2}
    configs = {
        "lstm": TrainConfig(
            algo="recurrentppo",
            total_steps=128,
            out_dir=str(root / "lstm"),
            frame_stack=1,
            hyperparams={
                "n_envs": 4,
                **TINY_NETS,
                "policy_kwargs": {"lstm_hidden_size": 16, "net_arch": [16], "log_std_init": 0.0},
            },
            **common,
        ),
        "stacked": TrainConfig(
            algo="ppo",
            total_steps=128,
            out_dir=str(root / "stacked"),
            frame_stack=3,
            hyperparams={"n_envs": 4, **TINY_NETS, "policy_kwargs": {"net_arch": [16]}},
            **common,
        ),
        "distilled": TrainConfig(
            algo="recurrentppo",
            out_dir=str(root / "distilled"),
            frame_stack=1,
            hyperparams={
                "n_envs": 4,
                "decimation": 10,
                "observation": {"features": ["reference", "motor_error", "reset_rest"]},
                "distill": {"iterations": 1, "steps": 5, "batch_size": 4},
                "policy_kwargs": {"lstm_hidden_size": 16, "net_arch": [16], "log_std_init": 0.0},
            },
            **common,
        ),
    }
    for config in configs.values():
        train(config, progress_bar=False)
    torch.set_num_threads(threads)
    return {key: config.out_dir for key, config in configs.items()}


@pytest.fixture(scope="module")
def memory_runs(sensor_runs, tmp_path_factory):
    """The raw-sensor runs and a tiny PPO run on the De Luca estimate whose actor sees
    the last three feature frames (``observation.frames``)."""
    config = TrainConfig(
        algo="ppo",
        state="deluca",
        total_steps=128,
        out_dir=str(tmp_path_factory.mktemp("observer-stacked")),
        observation={"frames": 3},
        env_kwargs=EPISODE,
        eval_freq=10**9,
        eval_episodes=2,
        hyperparams={"n_envs": 4, **TINY_NETS, "policy_kwargs": {"net_arch": [16]}},
    )
    train(config, progress_bar=False)
    return {**sensor_runs, "observer-stacked": config.out_dir}


class _Logged(Actor):
    """An actor that records the actions it returns, in the order of its calls."""

    def __init__(self, actor: Actor, log: list) -> None:
        self.actor, self.log = actor, log
        self.observation_size, self.action_size = actor.observation_size, actor.action_size

    def initial_memory(self):
        return self.actor.initial_memory()

    def act(self, observation, memory):
        action, memory = self.actor.act(observation, memory)
        self.log.append(np.array(action, dtype=float))
        return action, memory


def _own_predictions(run, seed: int, steps: int) -> np.ndarray:
    """The policy's own predict() on its training stack (one env, seed ``seed``), its LSTM
    state carried from step to step: the reference each comparison arm must reproduce."""
    env = spec_env(run.spec, {"episode_time": None})
    obs, _ = env.reset(seed=seed)
    state, start, actions = None, True, []
    for _ in range(steps):
        batch = run.normalizer.normalize_obs(obs[None]) if run.normalizer else obs[None]
        action, state = run.model.predict(
            batch, state=state, episode_start=np.array([start]), deterministic=True
        )
        start = False
        actions.append(action[0].astype(float))
        obs, *_ = env.step(action[0])
    env.close()
    return np.array(actions)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["lstm", "stacked", "observer-stacked", "distilled"])
def test_each_arm_gets_the_policys_own_prediction_with_its_memory(memory_runs, kind):
    """In one world of three arms (raw sensors, or the De Luca estimate seen in frames),
    the action of arm i at every policy step is the policy's predict() on the training
    stack seeded i, with its own LSTM state (or frame stack) carried per arm; an LSTM that
    forgot its state acts otherwise."""
    run = load_run(memory_runs[kind], trust_pickle=True)
    if kind == "observer-stacked":
        assert run.spec.frames == 3
    group = evaluation_runs(run, 3, 40)
    world = build_world(group)
    log: list = []
    law = world.controller.law
    law.actor = _Logged(law.actor, log)  # the arms act together: arm i is call i of a step
    policy_steps = 12
    loop = ClosedLoop(world, group)
    loop.start()
    for _ in range(policy_steps * run.decimation):
        loop.advance()
    world.close()
    logs = np.array(log).reshape(policy_steps, len(group.runs), -1).swapaxes(0, 1)
    for i, spec in enumerate(group.runs):
        reference = _own_predictions(run, spec.seed, policy_steps)
        np.testing.assert_allclose(np.array(logs[i]), reference, rtol=0, atol=1e-6)
    if kind == "lstm":  # the memory matters: restarting it every step changes the actions
        env = spec_env(run.spec, {"episode_time": None})
        obs, _ = env.reset(seed=40)
        forgetful = []
        for _ in range(policy_steps):
            run.start()
            forgetful.append(run.act(obs))
            obs, *_ = env.step(np.array(logs[0][len(forgetful) - 1], dtype=np.float32))
        env.close()
        assert np.max(np.abs(np.array(forgetful) - np.array(logs[0]))) > 1e-4


def _scenario(runs: dict, env_kwargs: dict, duration: float, seeds: list[int]) -> Scenario:
    scenario = Scenario.model_validate(
        {
            "name": "sensors",
            "duration": duration,
            "physics_dt": None,
            "seeds": seeds,
            "envs": [{"id": ENV_ID, "kwargs": env_kwargs}],
            "controllers": [{"name": "feedforward-state-feedback", "label": "eq13"}],
            "state_sources": ["deluca"],
        }
    )
    for folder in runs.values():
        scenario = with_trained_policy(scenario, folder, trust_pickle=True)
    return scenario


@pytest.mark.slow
def test_sensor_policy_rows_batched_equal_one_arm_per_world(sensor_runs, jobs_in_this_process):
    """`compare --policy RUN` of raw-sensor runs: a source 'sensors' is added for them,
    eq. (13) is not paired with it (skipped with the reason), and every metric of every
    row is the same batched and with --batch-size 1 (1e-12 relative)."""
    scenario = _scenario(
        sensor_runs, {"task_options": {"n_moves": 1, "move_time": 0.2}}, 0.3, [0, 1, 2]
    )
    runs, skipped = plan_runs(scenario)
    sources = {spec.labels["source"] for spec in runs if spec.controller.name == "trained-policy"}
    assert sources == {"sensors-policy"}
    assert any(
        s.labels["controller"] == "eq13" and "needs a state source, not raw sensors" in s.reason
        for s in skipped
    )
    batched = execute(runs, workers=1, progress=False)
    alone = execute(runs, workers=1, progress=False, batch_size=1)
    policy_rows = [r for r in batched if r.spec.controller.name == "trained-policy"]
    assert len(policy_rows) == 9 and all(r.ok for r in batched)
    for a, b in zip(batched, alone, strict=True):
        assert a.metrics.keys() == b.metrics.keys()
        for key, value in a.metrics.items():
            if key in ("sim_wall_ratio",):
                continue
            np.testing.assert_allclose(value, b.metrics[key], rtol=1e-12, atol=0, err_msg=key)
        assert a.episode_return == pytest.approx(b.episode_return, rel=1e-12)
    assert not any(k.startswith("est_rms") for r in policy_rows for k in r.metrics)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["lstm", "stacked", "distilled"])
def test_evaluate_run_is_the_comparison_row_of_the_same_run_seed_and_plant(
    sensor_runs, kind, jobs_in_this_process
):
    """evaluate_run runs on the comparison's loop: its tracking RMS of episode seed s is
    the track_rms of the comparison row of the same run, seed and plant, to 1e-12, and its
    return the sum of the env's rewards of that row's episode; one episode alone is the
    same arm of a batch."""
    run = load_run(sensor_runs[kind], trust_pickle=True)
    heavy = {"plant_scaling": {"link_mass": 1.2}}
    evaluation = evaluate_run(run, 3, 5, heavy)
    kwargs = {**run.spec.env_kwargs, **heavy}
    scenario = _scenario({kind: sensor_runs[kind]}, kwargs, EPISODE["episode_time"], [5, 6, 7])
    runs, _ = plan_runs(scenario)
    rows = {
        r.spec.seed: r
        for r in execute(runs, workers=1, progress=False)
        if r.spec.controller.name == "trained-policy"
    }
    for seed, rms, ret in zip(
        evaluation.seeds, evaluation.tracking_rms, evaluation.returns, strict=True
    ):
        assert rms == pytest.approx(rows[seed].metrics["track_rms"], rel=1e-12, abs=0)
        assert ret == pytest.approx(rows[seed].episode_return, rel=1e-12, abs=0)
    assert evaluate_run(run, 1, 6, heavy).tracking_rms[0] == evaluation.tracking_rms[1]
    assert all(0.0 <= s <= 1.0 for s in evaluation.saturated_actions)


@pytest.mark.slow
def test_bad_pairings_of_raw_sensors_are_refused(sensor_runs):
    """A raw-sensor policy fed an estimate fails its row naming the source to use; raw
    sensors take no initial estimate (refused when the runs are planned)."""
    run = load_run(sensor_runs["lstm"], trust_pickle=True)
    spec = evaluation_runs(run, 1, 0).first
    deluca = {"source": SourceEntry(name="deluca"), "observer_cls": source_class("deluca")}
    (result,) = run_group(RunGroup((dataclasses.replace(spec, **deluca),)))
    assert result.status.startswith("failed: ValueError")
    assert "pair it with the state source 'sensors'" in result.status
    data = {
        "envs": [ENV_ID],
        "controllers": [
            {
                "name": "trained-policy",
                "options": {"run": sensor_runs["lstm"], "trust_pickle": True},
            }
        ],
        "state_sources": [{"name": "sensors", "initial_estimate": [0.0] * 8}],
    }
    with pytest.raises(ScenarioError, match=r"state_sources\[0\]\.initial_estimate"):
        plan_runs(Scenario.model_validate(data))
    with pytest.raises(ValueError, match=r"^n_episodes must be an integer >= 1, got 0$"):
        evaluate_run(run, 0)
    env = spec_env(run.spec)
    model = env.unwrapped.model
    env.close()
    loaded = r"^options: best: applies only when the policy is a folder$"
    with pytest.raises(ValueError, match=loaded):
        PolicyController(model, 1e-3, run.policy, best=True)


@pytest.mark.slow
def test_benchmark_scores_a_raw_sensor_run_as_implementable(
    sensor_runs, tmp_path, jobs_in_this_process
):
    """`elastic-gym benchmark --run RUN` of a RecurrentPPO run on raw sensors: scored,
    source 'sensors', nothing privileged, not an oracle, and the scorecard says so."""
    from helpers import tiny_suite_data

    data = tiny_suite_data()
    data["categories"] = {"nominal": data["categories"]["nominal"]}
    suite_file = tmp_path / "tiny.yaml"
    suite_file.write_text(yaml.safe_dump(data))
    card = run_benchmark(
        {"run": sensor_runs["lstm"], "trust_pickle": True},
        suite=suite_file,
        output_dir=tmp_path / "card",
        workers=1,
        progress=False,
        figure=False,
    )
    assert card.entry.source == "sensors" and card.entry.privileged == []
    assert card.entry.oracle is False and card.entry.run["state"] == "sensors"
    assert card.scores.episodes == len(data["seeds"])
    assert all(status == "ok" for _, _, status, _ in card.episode_rows())
    assert "implementable: the raw sensors, no estimate and no ground truth" in (
        scorecard_markdown(card, load_suite(suite_file))
    )


def test_a_callable_policy_reads_the_raw_sensor_observation():
    """The `policy` controller on the source `sensors` gets each arm's sensor dict (no
    state estimate); the same rows batched and one arm per world."""
    seen: list[list[str]] = []

    def policy(obs):
        seen.append(sorted(obs))
        return np.clip(0.3 - obs["motor_position"], -1.0, 1.0)

    scenario = Scenario.model_validate(
        {
            "duration": 0.05,
            "seeds": [0, 1],
            "envs": [ENV_ID],
            "controllers": [{"name": "policy", "options": {"policy": policy}}],
            "state_sources": ["sensors"],
        }
    )
    runs, skipped = plan_runs(scenario)
    assert len(runs) == 2 and not skipped
    batched = execute(runs, workers=1, progress=False)
    alone = execute(runs, workers=1, progress=False, batch_size=1)
    assert seen[0] == ["acceleration", "motor_position", "reference"]
    for a, b in zip(batched, alone, strict=True):
        assert a.ok and a.metrics["track_rms"] == b.metrics["track_rms"]
        assert a.metrics["torque_rms"] > 0
