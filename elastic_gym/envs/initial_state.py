"""The initial state of an episode: at rest, or given by the reset's options.

``reset(options={"initial_state": {...}})`` may give q and q' (and theta, theta' of an
elastic arm); what is not given is the state at rest at the task's start configuration:
q' = 0 and, for an elastic arm, the static equilibrium of model (1) of De Luca et al.
2007, K (theta - q) = g(q), so theta = q + K^-1 g(q) and theta' = q'. The motor torque
that keeps such a state static is tau = K (theta - q) (rigid arms: tau = g(q)).
"""

from __future__ import annotations

import numpy as np

from elastic_gym.envs.batch_setup import check_within_limits
from elastic_gym.envs.config import ElasticResetOptions, RigidResetOptions
from elastic_gym.envs.plant import PlantArray
from elastic_gym.validation import numbers, validated


def initial_state_options(
    options: dict | None,
    elastic: bool,
    n_joints: int,
    max_velocity: float,
    joint_limits: tuple[np.ndarray, np.ndarray],
) -> dict[str, np.ndarray]:
    """The reset ``options`` validated (types and angle magnitudes by their model, the
    lengths, velocities and joint limits here): the given initial state by key."""
    model: type[ElasticResetOptions | RigidResetOptions] = (
        ElasticResetOptions if elastic else RigidResetOptions
    )
    given = validated(model, options, "options").initial_state
    n, values = n_joints, {}
    for key, value in ({} if given is None else given.model_dump(exclude_none=True)).items():
        speed = max_velocity if key.startswith("d") else None
        within = "" if speed is None else f" of magnitude <= {speed:g}"
        what = f"must be {n} numbers{within}"
        arr = numbers(value, f"options.initial_state.{key}:", what, [(n,)], bound=speed)
        if key == "q":
            check_within_limits("options.initial_state.q", arr, *joint_limits)
        values[key] = arr
    return values


def initial_state(
    q0: np.ndarray,
    given: dict[str, np.ndarray],
    arms: np.ndarray,
    plants: PlantArray,
    elastic: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(q, q', theta, theta') of ``arms`` starting at the task's configurations ``q0``
    (len(arms), n), the ``given`` values (`initial_state_options`) replacing the state at
    rest."""
    n = q0.shape[1]
    q = np.broadcast_to(given["q"], q0.shape).copy() if "q" in given else q0
    dq = np.broadcast_to(given.get("dq", np.zeros(n)), q.shape).copy()
    if not elastic:
        return q, dq, q, dq
    if "theta" in given:
        theta = np.broadcast_to(given["theta"], q.shape).copy()
    else:  # static equilibrium theta = q + K^-1 g(q)
        theta = q + plants.chain.select(arms).gravity(q) / plants.K[arms]
    dtheta = np.broadcast_to(given["dtheta"], q.shape).copy() if "dtheta" in given else dq
    return q, dq, theta, dtheta.copy()


def equilibrium_torque(
    q: np.ndarray, theta: np.ndarray, arms: np.ndarray, plants: PlantArray, elastic: bool
) -> np.ndarray:
    """Motor torque that keeps a static state of ``arms`` static (the reset reading)."""
    if elastic:
        return plants.K[arms] * (theta - q)
    return plants.chain.select(arms).gravity(q)
