"""What a deployed policy is, as one object: `PolicySpec`.

Everything that decides what a policy sees and what its actions mean is a field: the env
(``env_id``, ``env_kwargs``), the state source (``"true"``, an observer name, or raw
``"sensors"``) with the observer's options, the action's meaning
([`ActionConfig`][elastic_gym.policy.actions.ActionConfig]), the observation's features
([`ObservationConfig`][elastic_gym.policy.observation.ObservationConfig]), ``decimation``
(control periods per policy step), ``frame_stack`` (the raw-sensor frames seen; a state
source stacks ``observation.frames``) and the privileged inputs a critic saw in training
(``critic_state``, ``critic_plant``: appended only to the training stack). The builder
([`build_policy_env`][elastic_gym.policy.builder.build_policy_env]) makes the env stack
from it. The spec travels whole (training, evaluation, the comparison's controller, an
exported policy's manifest), never its fields one by one.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any

import gymnasium as gym
from gymnasium.vector import AutoresetMode
from pydantic import (
    AfterValidator,
    ConfigDict,
    Field,
    StrictBool,
    StrictInt,
    StrictStr,
    model_validator,
)

from elastic_gym.envs.config import MakeKwargsMapping
from elastic_gym.envs.ids import registered_env_id
from elastic_gym.model.identified import checked_model_file, load_identified_model
from elastic_gym.observers.registry import source_class
from elastic_gym.observers.sensors import SENSORS
from elastic_gym.policy.actions import ActionConfig
from elastic_gym.policy.observation import ObservationConfig
from elastic_gym.robots.catalog import get_robot
from elastic_gym.robots.spec import RobotSpec
from elastic_gym.validation import ConfigModel, only_when

PositiveInt = Annotated[StrictInt, Field(ge=1)]


def check_state_source(state: str) -> str:
    """Refuse a name that is no state source (``"true"``, an observer, ``"sensors"``),
    listing the valid ones."""
    source_class(state)
    return state


def check_model_robot(path: str, env_id: str, env_kwargs: Mapping[str, Any]) -> None:
    """Refuse an identified model file of another robot than the env's."""
    robot = env_kwargs.get("robot", gym.spec(env_id).kwargs.get("robot"))
    name = robot.name if isinstance(robot, RobotSpec) else get_robot(robot).name
    identified = load_identified_model(path).robot
    if identified != name:
        raise ValueError(
            f"model_file: {path!r} is a model of robot {identified!r}, not of the env's "
            f"robot {name!r}"
        )


class PolicySpec(ConfigModel):
    """A deployed policy's env, state source, action, observation, rate and privileged
    critic inputs (module docstring). Frozen; ``to_dict`` gives plain data.

    ``model_file``: an identified model file (`elastic-gym identify`) the observer, the
    action's gravity compensation and a residual's base controller build on instead of
    the env's nominal model; the simulated plant stays the env's."""

    model_config = ConfigDict(frozen=True)
    section = "policy"
    env_id: Annotated[StrictStr, AfterValidator(registered_env_id)]
    env_kwargs: MakeKwargsMapping = Field(default_factory=dict)
    state: Annotated[StrictStr, AfterValidator(check_state_source)] = "true"
    observer_options: dict[str, Any] = Field(default_factory=dict)
    action: ActionConfig = Field(default_factory=ActionConfig)
    observation: ObservationConfig = Field(default_factory=ObservationConfig)
    decimation: PositiveInt = 1
    frame_stack: PositiveInt | None = None  # raw sensors: frames seen (None: 1)
    critic_state: StrictBool = False
    critic_plant: StrictBool = False
    model_file: Annotated[StrictStr, AfterValidator(checked_model_file)] | None = None

    @model_validator(mode="after")
    def _consistent(self) -> PolicySpec:
        sensors = self.state == SENSORS
        only_when(not sensors, {"observer_options": self.observer_options}, "state is an observer")
        frames = {"observation.frames": self.observation.frames > 1}
        only_when(not sensors, frames, "the state is an observer or the truth")
        stacked = {"frame_stack": self.frame_stack}
        only_when(sensors, stacked, "the state is raw sensors (a state source stacks frames)")
        if self.model_file is not None:
            check_model_robot(self.model_file, self.env_id, self.env_kwargs)
        return self

    @property
    def sensors(self) -> bool:
        """True when the policy sees raw sensors (no observer)."""
        return self.state == SENSORS

    @property
    def frames(self) -> int:
        """Feature vectors the policy sees at once: ``frame_stack`` of raw sensors, the
        observation's ``frames`` of a state source."""
        return (self.frame_stack or 1) if self.sensors else self.observation.frames

    @property
    def critic(self) -> bool:
        """True when a critic saw privileged inputs in training."""
        return self.critic_state or self.critic_plant

    def make_env(
        self,
        n_arms: int | None = None,
        env_kwargs: dict | None = None,
        autoreset_mode: AutoresetMode = AutoresetMode.DISABLED,
    ) -> gym.Env | gym.vector.VectorEnv:
        """The env the spec names, under no policy wrapper: one env (``n_arms`` None) or
        ``n_arms`` arms of one PyBullet world (a vector env with ``autoreset_mode``);
        ``env_kwargs`` update the spec's key by key (e.g. an evaluation plant)."""
        kwargs = {**self.env_kwargs, **(env_kwargs or {})}
        if n_arms is None:
            only_when(
                autoreset_mode is AutoresetMode.DISABLED,
                {"autoreset_mode": autoreset_mode},
                "n_arms is given (a vector env)",
            )
            return gym.make(self.env_id, **kwargs)
        return gym.make_vec(
            self.env_id,
            num_envs=n_arms,
            vectorization_mode="vector_entry_point",
            autoreset_mode=autoreset_mode,
            **kwargs,
        )
