from neoedit.geometry.box import OrientedBox, points_in_box
from neoedit.geometry.transforms import invert_rigid, is_rigid, motion_about, rot_z, yaw_of_rotation

__all__ = [
    "OrientedBox",
    "invert_rigid",
    "is_rigid",
    "motion_about",
    "points_in_box",
    "rot_z",
    "yaw_of_rotation",
]
