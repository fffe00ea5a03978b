from neoedit.geometry.box import OrientedBox, points_in_box, points_in_boxes
from neoedit.geometry.transforms import invert_rigid, is_rigid, motion_about, rot_z, yaw_of_rotation

__all__ = [
    "OrientedBox",
    "invert_rigid",
    "is_rigid",
    "motion_about",
    "points_in_box",
    "points_in_boxes",
    "rot_z",
    "yaw_of_rotation",
]
