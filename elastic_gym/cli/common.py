"""What the subcommands share: option defaults from the config models, YAML mappings given
on the command line, and the check for the ``rl`` extra."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, RootModel

from elastic_gym.validation import validated


def default(model: type[BaseModel], field: str):
    """The default of a config model's field (the one place it is written)."""
    return model.model_fields[field].get_default(call_default_factory=True)


class _Mapping(RootModel[dict[str, Any]]):
    """A YAML mapping given on the command line (empty: ``{}``)."""


def yaml_mapping(text: str, option: str) -> dict:
    from elastic_gym.yaml_io import load_yaml

    return validated(_Mapping, load_yaml(text, option), prefix=option).root


def require_rl_extra(command: str) -> None:
    """Refuse an RL command clearly where stable-baselines3 / torch are not installed
    (``pip install .`` leaves them out; they come with the ``rl`` extra)."""
    try:
        import stable_baselines3  # noqa: F401
        import torch  # noqa: F401
    except ImportError as exc:
        raise RuntimeError(
            f"{command} needs the 'rl' extra ({exc}): pip install "
            "'elastic-gym[rl]' (CPU torch first: pip install torch --index-url "
            "https://download.pytorch.org/whl/cpu)"
        ) from None
