"""The simulated Black Metal robot: pure physics model plus a TCP server speaking the real protocol."""

from .robot import RobotParams, SimRobot
from .server import SimServer

__all__ = ["RobotParams", "SimRobot", "SimServer"]
