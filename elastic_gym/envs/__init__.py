"""Environments: PyBullet simulator of N arms, sensors, tasks, the single and vector envs."""

from elastic_gym.envs.arm_env import ArmEnv, ElasticArmEnv, RigidArmEnv
from elastic_gym.envs.batch import ArmBatch
from elastic_gym.envs.reward import RewardConfig
from elastic_gym.envs.sensors import AccelerometerConfig, EncoderConfig
from elastic_gym.envs.vector_env import ArmVectorEnv, ElasticArmVectorEnv, RigidArmVectorEnv

__all__ = [
    "AccelerometerConfig",
    "ArmBatch",
    "ArmEnv",
    "ArmVectorEnv",
    "ElasticArmEnv",
    "ElasticArmVectorEnv",
    "EncoderConfig",
    "RewardConfig",
    "RigidArmEnv",
    "RigidArmVectorEnv",
]
