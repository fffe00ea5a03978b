"""Named setups and the objects that ship with ``pybullet_data`` (no downloads needed)."""

from __future__ import annotations

import dataclasses

from neoedit.sim.spec import ObjectSpec, SetupSpec

SETUPS: dict[str, SetupSpec] = {
    # Setup A: long wooden table, Franka Panda at the short edge, light from the front right.
    "panda_wood": SetupSpec(),
    # Setup B: square grey-checker table, KUKA iiwa beside it, light from the back left, warmer.
    "kuka_checker": SetupSpec(
        name="kuka_checker",
        table_urdf="pybullet_data:table_square/table_square.urdf",
        table_top_m=0.64,
        robot_urdf="pybullet_data:kuka_iiwa/model.urdf",
        robot_base_m=(-0.55, 0.0, -0.64),  # on the floor beside the table, arm folded back
        robot_yaw_deg=0.0,
        robot_joints_rad=[0.0, -0.5, 0.0, 1.5, 0.0, 0.0, 0.0],
        light_direction=(-0.3, -0.5, 1.0),
        light_color=(1.0, 0.95, 0.88),
        ambient=0.6,
        diffuse=0.4,
        workspace_center_m=(0.02, 0.0, 0.04),
        workspace_half_extent_m=(0.2, 0.2),
    ),
}

# Objects from pybullet_data with natural-language names. Scale and base orientation make
# them tabletop-sized and upright.
CATALOG: dict[str, ObjectSpec] = {
    o.name: o
    for o in [
        ObjectSpec("red mug", "pybullet_data:objects/mug.urdf", scale=0.9, concave=True),
        ObjectSpec(
            "yellow rubber duck",
            "pybullet_data:duck_vhacd.urdf",
            rpy_deg=(90.0, 0.0, 0.0),
            scale=1.1,
        ),
        ObjectSpec("yellow lego brick", "pybullet_data:lego/lego.urdf", scale=1.8),
        ObjectSpec("soccer ball", "pybullet_data:soccerball.urdf", scale=0.09),
        ObjectSpec("wooden jenga block", "pybullet_data:jenga/jenga.urdf", scale=0.7),
        ObjectSpec(
            "pink teddy bear", "pybullet_data:teddy_vhacd.urdf", rpy_deg=(90.0, 0.0, 0.0), scale=1.0
        ),
        ObjectSpec("red ball", "pybullet_data:sphere2red.urdf", scale=0.07),
        ObjectSpec(
            "green cube", "pybullet_data:cube_small.urdf", scale=1.0, rgba=(0.15, 0.65, 0.25, 1.0)
        ),
        ObjectSpec(
            "blue cube", "pybullet_data:cube_small.urdf", scale=1.0, rgba=(0.15, 0.3, 0.85, 1.0)
        ),
        ObjectSpec(
            "orange cube", "pybullet_data:cube_small.urdf", scale=1.0, rgba=(0.95, 0.5, 0.1, 1.0)
        ),
    ]
}

# A paraphrase per object (used by the localisation benchmark).
PARAPHRASES: dict[str, str] = {
    "red mug": "mug",
    "yellow rubber duck": "duck toy",
    "yellow lego brick": "lego",
    "soccer ball": "football",
    "wooden jenga block": "wood block",
    "pink teddy bear": "teddy",
    "red ball": "red sphere",
    "green cube": "green block",
    "blue cube": "blue block",
    "orange cube": "orange block",
}


def catalog_object(name: str, x_m: float, y_m: float, yaw_deg: float = 0.0) -> ObjectSpec:
    """A catalogue object placed at (x, y) with a yaw."""
    return dataclasses.replace(CATALOG[name], position_m=(x_m, y_m, 0.01), yaw_deg=yaw_deg)
