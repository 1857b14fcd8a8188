"""Robot descriptions (URDF + elastic parameters + sensors), see
[`catalog`][elastic_gym.robots.catalog]."""

from elastic_gym.robots.catalog import ROBOTS, get_robot
from elastic_gym.robots.spec import AccelerometerMount, LinkFriction, RobotSpec

__all__ = ["ROBOTS", "AccelerometerMount", "LinkFriction", "RobotSpec", "get_robot"]
