"""Controllers that turn end-effector velocity commands into joint motion (Sawyer-Reach).

A small registry by name, so an ablation is one constructor argument (``controller=``):
- ``mink`` (default): mink differential IK to joint position targets, tracked by servos.
- ``osc``: robosuite's own OperationalSpaceController (torques every physics substep).
- ``joint_velocity``: damped least-squares resolved rates to joint velocity servos.
"""

from __future__ import annotations

from sili_robots.controllers.base import LEASH, ArmSpec, EndEffectorController
from sili_robots.errors import check_choice

DEFAULT_CONTROLLER = "mink"
CONTROLLER_NAMES = ("mink", "osc", "joint_velocity")


def controller_class(name: str) -> type[EndEffectorController]:
    """The controller class registered as ``name`` (ConfigError listing the choices if none)."""
    check_choice("controller", name, CONTROLLER_NAMES)
    if name == "mink":
        from sili_robots.controllers.mink_ik import MinkIKController

        return MinkIKController
    if name == "osc":
        from sili_robots.controllers.osc import RobosuiteOSCController

        return RobosuiteOSCController
    from sili_robots.controllers.joint_velocity import JointVelocityController

    return JointVelocityController


__all__ = [
    "CONTROLLER_NAMES",
    "DEFAULT_CONTROLLER",
    "LEASH",
    "ArmSpec",
    "EndEffectorController",
    "controller_class",
]
