"""The env a policy is trained on: sensors or a state source, residual, decimation, flattening.

Stack (bottom to top)::

    gym.make(env_id)                      1 kHz loop, sensors only
    ObserverWrapper / TrueStateWrapper    state source: an observer name or "true"
                                          ("sensors": raw observation, frame-stacked)
    ResidualAction                        optional: tau = controller + bounded correction
    ActionRepeat(decimation)              policy rate = 1 kHz / decimation
    FlattenObservation (+ frame stack)    Box observation for SB3 MlpPolicy
    RescaleAction(-1, 1)                  normalized actions (not needed with residual)
"""

from __future__ import annotations

import gymnasium as gym
from gymnasium.wrappers import FlattenObservation, FrameStackObservation, RescaleAction

import elastic_gym  # noqa: F401  (registers the env ids in worker processes)
from elastic_gym.observers import OBSERVERS, ObserverWrapper
from elastic_gym.training.wrappers import ActionRepeat, ResidualAction

SENSORS = "sensors"


def state_sources() -> list[str]:
    """Valid values of ``state``: raw sensors, or any observer name (``"true"`` = oracle)."""
    return [SENSORS, *OBSERVERS]


def check_state_source(state: str) -> None:
    if state not in state_sources():
        raise ValueError(f"unknown state source {state!r}; valid: {state_sources()}")


def make_policy_env(
    env_id: str,
    state: str = "true",
    env_kwargs: dict | None = None,
    observer_options: dict | None = None,
    decimation: int = 1,
    residual: str | None = None,
    residual_scale: float = 0.1,
    residual_options: dict | None = None,
    frame_stack: int = 1,
) -> gym.Env:
    """Build the wrapper stack of the module docstring."""
    check_state_source(state)
    env = gym.make(env_id, **(env_kwargs or {}))
    if state != SENSORS:
        env = ObserverWrapper(env, state, **(observer_options or {}))
    elif observer_options:
        raise ValueError("observer_options given but the state source is raw 'sensors'")
    if residual is not None:
        if state == SENSORS:
            raise ValueError("a residual policy needs a state source for its base controller")
        env = ResidualAction(env, residual, residual_scale, **(residual_options or {}))
    if decimation > 1:
        env = ActionRepeat(env, decimation)
    env = FlattenObservation(env)
    if frame_stack > 1:
        env = FlattenObservation(FrameStackObservation(env, frame_stack))
    if residual is None:
        env = RescaleAction(env, -1.0, 1.0)
    return env
