"""Nominal robot models: pinocchio (`RobotModel`) and batched serial chains.

``RobotModel`` (``robot_model``) is the designer's model of one arm: pinocchio rigid-body
dynamics of the URDF plus the elastic transmission. ``SerialChain`` (``chain``)
evaluates the same quantities for N arms at once (compiled loops over arms and joints),
the hot path of the batched simulation and of the vector observers.
"""

from elastic_gym.model.chain import SerialChain
from elastic_gym.model.robot_model import ParameterScaling, RobotModel

__all__ = ["ParameterScaling", "RobotModel", "SerialChain"]
