"""JSON Schemas: shipped up to date with the models, named by every shipped YAML file, and
as strict as the models on what they refuse."""

from __future__ import annotations

import json
import re
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
