"""The package's env ids: a bare name (``TwoLinkElastic-v0``) in the ``elastic_gym/``
namespace, checked against Gymnasium's registry."""

from __future__ import annotations

from typing import Any

from elastic_gym.validation import lookup

ENV_NAMESPACE = "elastic_gym/"


def registered_env_id(value: Any) -> str:
    """A registered Gymnasium env id; a bare name (``TwoLinkElastic-v0``) is looked up in
    the ``elastic_gym/`` namespace. ``ValueError`` lists the package's ids otherwise."""
    from gymnasium import registry

    env_id = value if not isinstance(value, str) or "/" in value else ENV_NAMESPACE + value
    if not (isinstance(env_id, str) and env_id in registry):  # refused, the package's ids listed
        lookup({k: k for k in registry if k.startswith(ENV_NAMESPACE)}, value, "env id")
    return env_id
