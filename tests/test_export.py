"""Policies as data: `elastic-gym export` writes an ONNX graph and a manifest whose
actions equal stable-baselines3's deterministic `predict` on recorded observations
(PPO on every state source, raw sensors included; RecurrentPPO on an elastic arm's
estimate, on raw sensors and on a rigid arm's estimate); the exported folder
loads and runs in the comparison without pickles; a run folder's pickles load only with
trust, and a payload planted in them never runs without it."""

from __future__ import annotations

import json
import pickle
import shutil
import zipfile
from pathlib import Path

import gymnasium as gym
import jsonschema
import numpy as np
import pytest
from helpers import N_ARMS, closed_loop_gap, spec_env

from elastic_gym.cli import main
from elastic_gym.controllers import make_controller
from elastic_gym.controllers.vector import make_vector_controller
from elastic_gym.observers import ObserverWrapper
from elastic_gym.policy import UntrustedPickleError, load_policy, read_spec
from elastic_gym.policy.manifest import GRAPH_FILE, MANIFEST_FILE, read_manifest
from elastic_gym.schemas import json_schema

pytest.importorskip("stable_baselines3")
pytest.importorskip("onnxruntime")
pytestmark = pytest.mark.usefixtures("single_thread_torch")

TWO_LINK = "elastic_gym/TwoLinkElastic-v0"
RIGID = "elastic_gym/TwoLinkRigid-v0"
TINY = {"n_envs": 2, "batches": 1, "n_steps": 16, "batch_size": 32, "n_epochs": 1}
NETS = {
    "ppo": {"net_arch": [16, 16]},
    "recurrentppo": {"net_arch": [16], "lstm_hidden_size": 8},
}
SOURCES = [  # (env, state source): every source of the elastic and of the rigid arm
    (TWO_LINK, "true"),
    (TWO_LINK, "deluca"),
    (TWO_LINK, "deluca-ideal"),
    (TWO_LINK, "ekf"),
    (TWO_LINK, "finite-difference"),
    (TWO_LINK, "sensors"),
    (RIGID, "reduced-order"),
    (RIGID, "solsona-puleston"),
    (RIGID, "nicosia-tomei"),
]
# the LSTM's memory and state inputs do not depend on the source: one of each observation
# kind (an elastic arm's estimate, raw sensors in frames, a rigid arm's estimate)
RECURRENT_SOURCES = [(TWO_LINK, "deluca"), (TWO_LINK, "sensors"), (RIGID, "reduced-order")]


def tiny_run(folder: Path, env_id: str, algo: str, state: str, **fields) -> Path:
    """A training run of 32 policy steps on 2 arms of one world in this process (short
    episodes; ``batches: 1``, no worker processes)."""
    from elastic_gym.training import TrainConfig, train

    hyperparams = {**TINY, "policy_kwargs": NETS[algo], **fields.pop("hyperparams", {})}
    config = TrainConfig(
        env_id=env_id,
        algo=algo,
        state=state,
        total_steps=32,
        out_dir=str(folder),
        env_kwargs={"episode_time": 0.1},
        hyperparams=hyperparams,
        frame_stack=2,
        eval_freq=10**6,
        eval_episodes=1,
        **fields,
    )
    train(config, progress_bar=False)
    return folder


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """`tiny_run` by its arguments, each trained once for the module; a test that changes
    a run's files changes a copy."""
    trained: dict[str, Path] = {}

    def run(env_id: str, algo: str, state: str, **fields) -> Path:
        key = repr((env_id, algo, state, fields))
        if key not in trained:
            folder = tmp_path_factory.mktemp("run") / "run"
            trained[key] = tiny_run(folder, env_id, algo, state, **fields)
        return trained[key]

    return run


def export(run: Path, output: Path, *extra: str) -> int:
    return main(["export", str(run), "--output", str(output), *extra])


def recorded_observations(run, steps: int = 12) -> list[np.ndarray]:
    """The deployed stack's observations of one episode driven by the run's own actions."""
    env = spec_env(run.spec)
    obs, _ = env.reset(seed=5)
    run.start()
    seen = [obs]
    for _ in range(steps):
        obs, *_, terminated, truncated, _ = env.step(run.act(obs))
        seen.append(obs)
        if terminated or truncated:
            break
    env.close()
    return seen


def assert_onnx_is_predict(run_folder: Path, exported: Path) -> None:
    """onnxruntime's actions equal SB3's deterministic predict (memory carried) to 1e-5
    on the observations of an episode."""
    from elastic_gym.training import load_run

    run = load_run(run_folder, trust_pickle=True)
    observations = recorded_observations(run)
    policy = load_policy(exported)
    memory = policy.actor.initial_memory()
    run.start()
    for obs in observations:
        action, memory = policy.actor.act(obs, memory)
        np.testing.assert_allclose(action, run.act(obs), rtol=0, atol=1e-5)
    assert len(observations) > 5


@pytest.mark.slow
@pytest.mark.parametrize(
    ("algo", "env_id", "state"),
    [("ppo", *source) for source in SOURCES]
    + [("recurrentppo", *source) for source in RECURRENT_SOURCES],
)
def test_the_exported_graph_acts_as_sb3_predicts(tmp_path, runs, algo, env_id, state):
    run = runs(env_id, algo, state)
    assert export(run, tmp_path / "exported") == 0
    assert_onnx_is_predict(run, tmp_path / "exported")
    manifest = read_manifest(tmp_path / "exported")
    assert (manifest.env_id, manifest.state) == (env_id, state)
    frames = 2 if state == "sensors" else 1
    assert manifest.observation.frames == frames
    assert manifest.observation.size == frames * manifest.observation.frame_size


@pytest.mark.slow
def test_a_residual_with_a_privileged_critic_exports_its_actor_only(tmp_path, runs):
    """The critic's privileged entries are no input of the graph: the actor's m entries
    are, normalized with the first m statistics (the actor slices the rest off)."""
    run = runs(
        TWO_LINK,
        "ppo",
        "deluca",
        action={"kind": "residual", "residual": "feedforward-state-feedback"},
        hyperparams={"critic_state": True},
    )
    assert export(run, tmp_path / "exported") == 0
    assert_onnx_is_predict(run, tmp_path / "exported")
    policy = load_policy(tmp_path / "exported")
    assert policy.spec.critic_state and policy.spec.action.kind == "residual"
    from elastic_gym.training import load_run

    trained = load_run(run, trust_pickle=True)
    privileged = trained.model.policy.privileged_size
    assert privileged > 0
    assert policy.actor.observation_size == trained.model.observation_space.shape[0] - privileged


@pytest.mark.slow
def test_the_manifest_says_what_each_input_is_and_satisfies_its_schema(tmp_path, runs):
    run = runs(TWO_LINK, "recurrentppo", "sensors")
    assert export(run, tmp_path / "exported") == 0
    data = json.loads((tmp_path / "exported" / MANIFEST_FILE).read_text())
    jsonschema.Draft202012Validator(json_schema("policy")).validate(data)
    manifest = read_manifest(tmp_path / "exported")
    names = [block.name for block in manifest.observation.features]
    assert names == ["reference", "motor_error", "acceleration", "last_action"]
    sizes = {block.name: block.size for block in manifest.observation.features}
    model = gym.make(TWO_LINK).unwrapped.model
    assert sizes["acceleration"] == 3 * model.n_sensors and sizes["motor_error"] == model.n
    assert manifest.policy_rate == pytest.approx(1.0 / (10 * manifest.control_dt))
    assert manifest.action.kind == "motor-offset" and manifest.action.kp is not None
    np.testing.assert_array_equal(manifest.action.torque_limit, model.torque_limit)
    inputs = [t.name for t in manifest.graph.inputs]
    outputs = [t.name for t in manifest.graph.outputs]
    assert inputs == ["observation", "hidden_state", "cell_state"]
    assert outputs == ["action", "hidden_state_out", "cell_state_out"]
    assert manifest.graph.inputs[1].shape == [1, "batch", 8]
    assert manifest.provenance.algo == "recurrentppo"
    assert set(manifest.provenance.run_files) == {"model.zip", "vecnormalize.pkl", "config.yaml"}
    # the files of the folder: small, and no pickle
    files = sorted(p.name for p in (tmp_path / "exported").iterdir())
    assert files == sorted([GRAPH_FILE, MANIFEST_FILE])


@pytest.mark.slow
def test_a_changed_graph_or_manifest_is_refused(tmp_path, runs):
    run = runs(TWO_LINK, "ppo", "true")
    exported = tmp_path / "exported"
    assert export(run, exported) == 0
    load_policy(exported)
    changed = tmp_path / "changed"
    shutil.copytree(exported, changed)
    with open(changed / GRAPH_FILE, "ab") as handle:
        handle.write(b"\0")
    with pytest.raises(ValueError, match="SHA-256 is not the manifest's"):
        load_policy(changed)
    shutil.copytree(exported, changed, dirs_exist_ok=True)
    data = json.loads((changed / MANIFEST_FILE).read_text())
    data["spec"]["action"]["kind"] = "teleport"
    (changed / MANIFEST_FILE).write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"policy\.json: spec\.action\.kind: Input should be"):
        load_policy(changed)
    # the export refuses a folder holding files, and replaces it with --overwrite
    with pytest.raises(SystemExit) as exit_info:
        export(run, exported)
    assert exit_info.value.code == 2
    assert export(run, exported, "--overwrite") == 0


def test_the_exported_policy_runs_in_the_comparison_as_the_run_does(tmp_path, runs):
    """The comparison's controller on the exported policy and on the trusted run folder:
    torques within the actions' float32 rounding on the same observations; N arms of the
    exported policy's vector twin are N single controllers (per-arm LSTM memory)."""
    run = runs(TWO_LINK, "recurrentppo", "deluca")
    assert export(run, tmp_path / "exported") == 0
    env = ObserverWrapper(gym.make(TWO_LINK, episode_time=0.3), "deluca")
    model = env.unwrapped.model
    exported = make_controller("trained-policy", model, 1e-3, policy=str(tmp_path / "exported"))
    trusted = make_controller("trained-policy", model, 1e-3, run=str(run), trust_pickle=True)
    obs, info = env.reset(seed=2)
    public = {key: info[key] for key in ("time", "reference")}
    exported.reset(obs, public)
    trusted.reset(obs, public)
    gaps = []
    for _ in range(200):
        torque = exported(obs, public)
        gaps.append(np.max(np.abs(torque - trusted(obs, public)) / model.torque_limit))
        obs, _, terminated, truncated, info = env.step(torque)
        public = {key: info[key] for key in ("time", "reference")}
        if terminated or truncated:
            break
    env.close()
    assert max(gaps) < 1e-4
    from elastic_gym.training import evaluate_run, load_run

    exported_rms = evaluate_run(load_policy(tmp_path / "exported"), 2, 7).tracking_rms
    trusted_rms = evaluate_run(load_run(run, trust_pickle=True), 2, 7).tracking_rms
    np.testing.assert_allclose(exported_rms, trusted_rms, rtol=1e-3)
    options = {"policy": str(tmp_path / "exported")}
    batched = make_vector_controller("trained-policy", model, 1e-3, N_ARMS, **options)
    singles = [make_controller("trained-policy", model, 1e-3, **options) for _ in range(N_ARMS)]
    assert closed_loop_gap(TWO_LINK, batched, singles) == 0.0


# ------------------------------------------------------------------ pickles are code
class Payload:
    """Unpickles as ``inner`` after writing ``marker``: what a planted pickle does."""

    def __init__(self, marker: Path, inner: bytes) -> None:
        self.marker, self.inner = str(marker), inner

    def __reduce__(self):
        load = f"__import__('pickle').loads({self.inner!r})"
        code = f"(open({self.marker!r}, 'w').write('ran'), {load})[1]"
        return (eval, (code,))


def plant(run: Path, marker: Path) -> None:
    """Replace the run's vecnormalize.pkl by one that writes ``marker`` when unpickled."""
    path = run / "vecnormalize.pkl"
    path.write_bytes(pickle.dumps(Payload(marker, path.read_bytes())))


@pytest.mark.slow
def test_a_planted_pickle_never_runs_without_trust_and_loads_with_it(tmp_path, runs, capsys):
    run = Path(shutil.copytree(runs(TWO_LINK, "ppo", "deluca"), tmp_path / "run"))
    marker = tmp_path / "marker"
    plant(run, marker)
    out = tmp_path / "out"
    for argv in (
        ["compare", "--policy", str(run), "--output", str(out), "--no-progress"],
        ["benchmark", "--run", str(run), "--output", str(out), "--no-progress"],
    ):
        with pytest.raises(SystemExit) as exit_info:
            main(argv)
        assert exit_info.value.code == 2
        err = capsys.readouterr().err
        assert "runs code stored in the files" in err and f"elastic-gym export {run}" in err
    with pytest.raises(UntrustedPickleError, match="elastic-gym export"):
        load_policy(run)
    with pytest.raises(UntrustedPickleError):
        make_controller("trained-policy", gym.make(TWO_LINK).unwrapped.model, 1e-3, run=str(run))
    assert read_spec(run).state == "deluca"  # config.yaml is data
    # the export reads the statistics as data: the planted global is refused, not called
    with pytest.raises(SystemExit) as exit_info:
        export(run, tmp_path / "exported")
    assert exit_info.value.code == 2
    assert "names builtins.eval" in capsys.readouterr().err
    assert not marker.exists() and not out.exists() and not (tmp_path / "exported").exists()
    policy = load_policy(run, trust_pickle=True)  # the user said they trust it
    assert marker.read_text() == "ran"
    assert policy.actor.normalizer.obs_rms.mean.shape == (policy.actor.observation_size,)


@pytest.mark.slow
def test_the_export_reads_weights_only_from_the_model_zip(tmp_path, runs, capsys):
    """A model.zip whose policy.pth holds a pickled object, not tensors, is refused by
    torch's weights-only loader: nothing runs."""
    run = Path(shutil.copytree(runs(TWO_LINK, "ppo", "true"), tmp_path / "run"))
    marker = tmp_path / "marker"
    archive = run / "model.zip"
    with zipfile.ZipFile(archive) as source:
        members = {name: source.read(name) for name in source.namelist()}
    import torch

    planted = tmp_path / "planted.pth"
    torch.save({"w": Payload(marker, pickle.dumps(1))}, planted)
    members["policy.pth"] = planted.read_bytes()
    with zipfile.ZipFile(archive, "w") as target:
        for name, data in members.items():
            target.writestr(name, data)
    with pytest.raises(SystemExit) as exit_info:
        export(run, tmp_path / "exported")
    assert exit_info.value.code == 2
    assert "holds no SB3 policy weights" in capsys.readouterr().err
    assert not marker.exists()


def test_a_policy_controller_without_its_policy_is_refused_before_any_run(
    tmp_path, jobs_in_this_process
):
    from elastic_gym.evaluation import Scenario, ScenarioError, compare

    scenario = Scenario.from_dict(
        {
            "envs": ["TwoLinkRigid-v0"],
            "controllers": ["trained-policy"],
            "state_sources": ["true"],
            "duration": 0.01,
        }
    )
    out = tmp_path / "out"
    with pytest.raises(ScenarioError, match=r"^controllers\[0\]\.options: .*give one of policy"):
        compare(scenario, output_dir=out, workers=1, progress=False)
    assert not out.exists()
