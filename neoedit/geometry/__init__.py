from neoedit.geometry.box import OrientedBox
from neoedit.geometry.transforms import rot_z, yaw_of_rotation

__all__ = ["OrientedBox", "rot_z", "yaw_of_rotation"]
