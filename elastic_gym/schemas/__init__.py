"""JSON Schemas of the files the package reads (YAML, scorecard JSON), for editors and checks.

`SCHEMAS` maps a schema name to the pydantic model that validates those files
(``"module:Model"``; a model whose module is not installed is left out). The generated
schemas ship beside this module as ``<name>.json``, and every shipped YAML file names
its schema in its first line, ``# yaml-language-server: $schema=<relative path>``; a run
folder's ``config.yaml`` (written anywhere) names the installed ``run.json`` by its
``file://`` URI ([`schema_comment`][elastic_gym.schemas.schema_comment]).
Regenerate them after changing a model with::

    elastic-gym schema --write
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path

from pydantic import BaseModel

from elastic_gym.runtime.atomic import write_text
from elastic_gym.validation import lookup

SCHEMA_DIR = Path(__file__).resolve().parent
SCHEMAS = {
    "scenario": "elastic_gym.evaluation.scenario:Scenario",  # presets, compare --config
    "train": "elastic_gym.training.config:HyperparameterFile",  # hyper-parameter files
    "suite": "elastic_gym.benchmark.suite:SuiteConfig",
    "run": "elastic_gym.training.config:TrainConfig",  # a run folder's config.yaml
    "log": "elastic_gym.logs.sidecar:LogSidecar",  # a sensor log's sidecar <log>.yaml
    "robot": "elastic_gym.robots.description:RobotDescription",  # robot description files
    "model": "elastic_gym.model.identified:IdentifiedModel",  # elastic-gym identify's model file
    "scorecard": "elastic_gym.benchmark.card:Scorecard",  # a benchmark scorecard (JSON)
    "policy": "elastic_gym.policy.manifest:Manifest",  # an exported policy's policy.json
}


def schema_models() -> dict[str, type[BaseModel]]:
    """The models of `SCHEMAS` that can be imported here."""
    models = {}
    for name, target in SCHEMAS.items():
        module, _, attr = target.partition(":")
        try:
            models[name] = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError):
            continue
    return models


def json_schema(name: str) -> dict:
    """The JSON Schema (draft 2020-12) of the files validated by model ``name``."""
    model = lookup(schema_models(), name, "schema")
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        **model.model_json_schema(by_alias=True),
    }


def schema_text(name: str) -> str:
    """[`json_schema`][elastic_gym.schemas.json_schema] as the text of the shipped file."""
    return json.dumps(json_schema(name), indent=2, sort_keys=True) + "\n"


def schema_comment(name: str) -> str:
    """The first line of a written YAML file validated by schema ``name``: the installed
    schema file's absolute ``file://`` URI (valid wherever the file is written, on the
    machine and installation that wrote it)."""
    return f"# yaml-language-server: $schema={(SCHEMA_DIR / f'{name}.json').as_uri()}\n"


def write_schemas(directory: Path = SCHEMA_DIR) -> list[Path]:
    """Write every schema as ``<name>.json`` into ``directory``; return the paths."""
    paths = []
    for name in schema_models():
        paths.append(write_text(Path(directory) / f"{name}.json", schema_text(name)))
    return paths
