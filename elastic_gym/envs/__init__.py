"""Environments: PyBullet simulator, sensors, tasks and the Gymnasium env classes."""

from elastic_gym.envs.arm_env import ArmEnv, ElasticArmEnv, RigidArmEnv
from elastic_gym.envs.reward import RewardConfig
from elastic_gym.envs.sensors import AccelerometerConfig, EncoderConfig

__all__ = [
    "AccelerometerConfig",
    "ArmEnv",
    "ElasticArmEnv",
    "EncoderConfig",
    "RewardConfig",
    "RigidArmEnv",
]
