"""elastic-gym: robot arms with elastic joints under partial sensing, for control and RL.

Importing the package registers the environments (namespace ``elastic_gym``)::

    import gymnasium as gym
    import elastic_gym  # noqa: F401

    env = gym.make("elastic_gym/TwoLinkElastic-v0")
"""

from gymnasium.envs.registration import register, registry

__version__ = "0.2.0"

# id -> (joint kind, robot). Episodes end after the env kwarg ``episode_time`` (3 s by
# default) of simulated time, whatever the control period, so no TimeLimit is registered.
ENVIRONMENTS = {
    "TwoLinkElastic-v0": ("Elastic", "two_link_elastic"),
    "KR15Elastic-v0": ("Elastic", "kr15_elastic"),
    "IiwaElastic-v0": ("Elastic", "iiwa_elastic"),
    "TwoLinkRigid-v0": ("Rigid", "two_link_rigid"),
    "TwoLinkRigidFriction-v0": ("Rigid", "two_link_friction"),
}


def _register_all() -> None:
    for name, (kind, robot) in ENVIRONMENTS.items():
        env_id = f"elastic_gym/{name}"
        if env_id in registry:
            continue
        register(
            id=env_id,
            entry_point=f"elastic_gym.envs:{kind}ArmEnv",
            vector_entry_point=f"elastic_gym.envs:{kind}ArmVectorEnv",
            kwargs={"robot": robot},
        )


_register_all()

ENV_IDS = tuple(f"elastic_gym/{name}" for name in ENVIRONMENTS)

__all__ = ["ENV_IDS", "__version__"]
