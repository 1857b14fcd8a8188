"""JSON Schemas: shipped up to date with the models, named by every shipped YAML file, and
as strict as the models on what they refuse."""

from __future__ import annotations

import json
import re
import runpy
from pathlib import Path

import jsonschema
import pytest
import yaml

from elastic_gym.cli import main
from elastic_gym.evaluation import Scenario, ScenarioError, load_scenario
from elastic_gym.schemas import SCHEMA_DIR, json_schema, schema_models, schema_text
from elastic_gym.training.config import load_hyperparams_file

ROOT = Path(__file__).resolve().parent.parent
HEADER = re.compile(r"^# yaml-language-server: \$schema=(\S+)\n")
SHIPPED = {  # folder, file pattern -> the schema its files must name
    ("elastic_gym/presets", "*.yaml"): "scenario",
    ("examples", "*.yaml"): "scenario",
    ("examples", "*.yml"): "train",  # the RL Zoo recipe: a hyper-parameter file
    ("elastic_gym/training/hyperparams", "*.yaml"): "train",
}
FILES = [
    (path, name)
    for (folder, pattern), name in SHIPPED.items()
    for path in sorted((ROOT / folder).glob(pattern))
]


def validator(name: str) -> jsonschema.Draft202012Validator:
    schema = json_schema(name)
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


def test_the_shipped_schemas_are_those_of_the_models():
    """Regenerate with ``elastic-gym schema --write`` after changing a model."""
    assert {"scenario", "train"} <= set(schema_models())
    for name in schema_models():
        assert (SCHEMA_DIR / f"{name}.json").read_text() == schema_text(name), name


@pytest.mark.slow
def test_every_shipped_yaml_file_exists_names_its_schema_and_satisfies_it():
    assert len(FILES) >= 14
    for path, name in FILES:
        text = path.read_text()
        match = HEADER.match(text)
        assert match, f"{path} does not start with the yaml-language-server comment"
        assert (path.parent / match[1]).resolve() == SCHEMA_DIR / f"{name}.json", path
        data = yaml.safe_load(text)
        errors = [e.message for e in validator(name).iter_errors(data)]
        assert not errors, f"{path}: {errors}"
        if name == "scenario":  # the model accepts what the schema accepts
            load_scenario(path)
        elif path.suffix == ".yaml":
            load_hyperparams_file(path)


@pytest.mark.parametrize(
    ("change", "path"),
    [
        ({"duraton": 1.0}, "duraton"),
        ({"duration": -1.0}, "duration"),
        ({"duration": True}, "duration"),
        ({"seeds": [0, 0]}, "seeds"),
        ({"seeds": [-1]}, "seeds[0]"),
        ({"physics_dt": 2e-3}, "physics_dt"),
        ({"controllers": [{"name": "motor-pd", "gains": {}}]}, "controllers[0].gains"),
        ({"state_sources": [False]}, "state_sources[0]"),
        ({"sweeps": {"s": {"parameter": "sensor_delay", "values": [1]}}}, "sweeps.s.nominal"),
        ({"sweeps": {"s": {"parameter": "a b", "nominal": 0, "values": [1]}}}, "sweeps.s"),
        (
            {"sweeps": {"s": {"parameter": "x", "nominal": 0, "range": [0, 1], "num": 1}}},
            "sweeps.s",
        ),
    ],
)
def test_what_the_schema_refuses_the_model_refuses_at_the_same_field(change, path):
    data = {
        "envs": ["TwoLinkRigid-v0"],
        "controllers": ["motor-pd"],
        "state_sources": [True],
        **change,
    }
    assert not validator("scenario").is_valid(data)
    with pytest.raises(ScenarioError) as info:
        Scenario.from_dict(data)
    assert str(info.value).startswith(path), str(info.value)


def test_the_train_schema_types_our_own_keys():
    check = validator("train")
    assert check.is_valid({"default": {"n_envs": 4, "learning_rate": "lin_1e-3"}})
    for entry in ({"n_envs": 0}, {"normalize": "yes"}, {"batches": [3]}, {"decimation": 1.5}):
        assert not check.is_valid({"default": entry}), entry
    assert not check.is_valid({"default": 3})


def test_cli_prints_the_schema(capsys):
    assert main(["schema", "scenario"]) == 0
    assert json.loads(capsys.readouterr().out) == json_schema("scenario")
    with pytest.raises(SystemExit) as info:
        main(["schema", "nope"])
    assert info.value.code == 2


def test_python_dash_m_runs_the_same_command_line(monkeypatch, capsys):
    """``python -m elastic_gym.cli schema scenario`` is the console script's command: the
    same output, its exit status handed to the shell."""
    monkeypatch.setattr("sys.argv", ["elastic_gym.cli", "schema", "scenario"])
    with pytest.raises(SystemExit) as info:
        runpy.run_module("elastic_gym.cli", run_name="__main__")
    assert info.value.code == 0
    assert json.loads(capsys.readouterr().out) == json_schema("scenario")


def test_a_freshly_written_run_config_names_the_run_schema_and_satisfies_it(tmp_path):
    from elastic_gym.training import RunFolder, TrainConfig

    config = TrainConfig(
        out_dir=str(tmp_path / "run"),
        env_kwargs={"plant_scaling": {"link_mass": [1.1, 1.2]}, "sensor_delay": 1},
        action={"kind": "residual", "residual": "feedforward-state-feedback"},
    )
    folder = RunFolder(tmp_path / "run")
    folder.path.mkdir()
    folder.write_config(config)
    text = (folder.path / "config.yaml").read_text()
    match = HEADER.match(text)
    assert match, text.splitlines()[0]
    assert match[1] == (SCHEMA_DIR / "run.json").as_uri()  # absolute: valid from any folder
    data = yaml.safe_load(text)
    errors = [e.message for e in validator("run").iter_errors(data)]
    assert not errors, errors
    assert TrainConfig.from_dict(data) == config
    bad = {**data, "env_kwargs": {"plant_scaling": {"link_mass": -1}}}
    assert not validator("run").is_valid(bad)
    with pytest.raises(ValueError, match=r"^env_kwargs\.plant_scaling\.link_mass: must be"):
        TrainConfig.from_dict(bad)


def test_the_scenario_schema_types_the_env_kwargs_by_the_envs_own_model():
    check = validator("scenario")
    base = {"controllers": ["motor-pd"], "state_sources": [True]}
    env = {"id": "TwoLinkElastic-v0", "kwargs": {"plant_scaling": {"link_mass": 1.3}}}
    assert check.is_valid({**base, "envs": [env]})
    for kwargs, path in [
        ({"plant_scaling": {"link_mass": -1}}, "envs[0].kwargs.plant_scaling.link_mass"),
        ({"plant_scaling": {"link_mas": 1}}, "envs[0].kwargs.plant_scaling.link_mas"),
        ({"sensor_delay": 1.5}, "envs[0].kwargs.sensor_delay"),
        ({"tsk": "regulation"}, "envs[0].kwargs.tsk"),
        ({"accelerometer": "noisy"}, "envs[0].kwargs.accelerometer"),
    ]:
        data = {**base, "envs": [{**env, "kwargs": kwargs}]}
        assert not check.is_valid(data), kwargs
        with pytest.raises(ScenarioError) as info:
            Scenario.from_dict(data)
        assert str(info.value).startswith(f"{path}:"), str(info.value)
    assert check.is_valid({**base, "envs": [{**env, "kwargs": {"accelerometer": "ideal"}}]})
