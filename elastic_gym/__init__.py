"""elastic-gym: robot arms with elastic joints under partial sensing, for control and RL.

Importing the package registers the environments (namespace ``elastic_gym``)::

    import gymnasium as gym
    import elastic_gym  # noqa: F401

    env = gym.make("elastic_gym/TwoLinkElastic-v0")
"""

from gymnasium.envs.registration import register, registry

__version__ = "0.1.0"

EPISODE_STEPS = 3000  # 3 s at the default 1 kHz control rate

ENVIRONMENTS = {
    "TwoLinkElastic-v0": ("elastic_gym.envs:ElasticArmEnv", "two_link_elastic"),
    "KR15Elastic-v0": ("elastic_gym.envs:ElasticArmEnv", "kr15_elastic"),
    "IiwaElastic-v0": ("elastic_gym.envs:ElasticArmEnv", "iiwa_elastic"),
    "TwoLinkRigid-v0": ("elastic_gym.envs:RigidArmEnv", "two_link_rigid"),
    "TwoLinkRigidFriction-v0": ("elastic_gym.envs:RigidArmEnv", "two_link_friction"),
}


def _register_all() -> None:
    for name, (entry_point, robot) in ENVIRONMENTS.items():
        env_id = f"elastic_gym/{name}"
        if env_id in registry:
            continue
        register(
            id=env_id,
            entry_point=entry_point,
            kwargs={"robot": robot},
            max_episode_steps=EPISODE_STEPS,
        )


_register_all()

ENV_IDS = tuple(f"elastic_gym/{name}" for name in ENVIRONMENTS)

__all__ = ["ENV_IDS", "__version__"]
