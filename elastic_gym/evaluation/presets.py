"""The scenarios shipped in ``elastic_gym/presets`` and scenario YAML files."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from elastic_gym.evaluation.scenario import Scenario, ScenarioError
from elastic_gym.validation import lookup
from elastic_gym.yaml_io import YAMLInputError, load_yaml

PRESET_DIR = Path(__file__).resolve().parent.parent / "presets"
DEFAULT_PRESET = "default"


def list_presets() -> list[str]:
    """Names of the presets shipped in ``elastic_gym/presets``."""
    return sorted(path.stem for path in PRESET_DIR.glob("*.yaml"))


def preset_path(name: str) -> Path:
    lookup(dict.fromkeys(list_presets()), name, "preset")
    return PRESET_DIR / f"{name}.yaml"


def load_preset(name: str = DEFAULT_PRESET) -> Scenario:
    """A shipped preset by name (``elastic-gym compare --preset NAME``)."""
    return load_scenario(preset_path(name), name=name)


def load_scenario(path: str | Path, name: str | None = None) -> Scenario:
    """A scenario from a YAML file; the name defaults to the file's ``name`` field or stem."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"scenario file {str(path)!r} does not exist")
    try:
        data = load_yaml(path)
    except YAMLInputError as exc:
        raise ScenarioError(exc.where, exc.problem) from None
    named = data.get("name") if isinstance(data, Mapping) else None  # else: refused below
    return Scenario.from_dict(data, name or named or path.stem)
