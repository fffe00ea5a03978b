"""Scene specifications as plain data (dataclasses; :mod:`neoedit.sim.specfile` reads them
from YAML/JSON with field-named errors).

A scene = a setup (table, robot arm, lighting), objects with natural-language names and
initial poses, a scan protocol (image size, trajectory) and an ordered list of actions.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal

from pydantic import ConfigDict

from neoedit.utils.aruco import DICTIONARIES

Vec3 = tuple[float, float, float]
_FORBID_EXTRA = ConfigDict(extra="forbid")  # unknown keys in a spec are errors


@dataclass
class ObjectSpec:
    """One object on the table."""

    __pydantic_config__ = _FORBID_EXTRA

    name: str
    """Natural-language name, unique in the scene (e.g. "red mug"); queries use it."""
    urdf: str
    """``pybullet_data:REL`` (ships with pybullet), ``objects_dir:REL`` (a folder given with
    ``--objects-dir``; a sub-folder means its ``model.urdf``) or a path relative to the spec file."""
    position_m: Vec3 = (0.0, 0.0, 0.0)
    """x, y on the table (world metres); z is a drop height above the table top."""
    yaw_deg: float = 0.0
    """Rotation about +z applied after ``rpy_deg``."""
    rpy_deg: Vec3 = (0.0, 0.0, 0.0)
    """Base orientation of the model (e.g. to stand a y-up mesh upright)."""
    scale: float = 1.0
    """Uniform scale passed to PyBullet (``globalScaling``)."""
    rgba: tuple[float, float, float, float] | None = None
    """Override colour; None keeps the model's own colour/texture."""
    concave: bool = False
    """Collide with the convex parts of the visual mesh (V-HACD, computed once and cached)
    instead of the convex hulls of the collision mesh's parts, PyBullet's default: a mug's
    inside stays open."""


@dataclass
class MarkerSpec:
    """One ArUco marker lying on the table (:mod:`neoedit.sim.markers` draws it)."""

    __pydantic_config__ = _FORBID_EXTRA

    id: int
    center_m: tuple[float, float]
    """x, y of its centre on the table top (world metres)."""
    side_m: float = 0.08
    """Side of the black square (a white quiet zone of a quarter side surrounds it)."""
    yaw_deg: float = 0.0
    dictionary: str = "4X4_50"

    def __post_init__(self) -> None:
        if self.dictionary not in DICTIONARIES:
            raise ValueError(f"dictionary must be one of {', '.join(DICTIONARIES)}")
        if not 0 <= self.id < DICTIONARIES[self.dictionary]:
            raise ValueError(f"id must be in 0..{DICTIONARIES[self.dictionary] - 1}")
        if not 0.005 <= self.side_m <= 1.0:
            raise ValueError("side_m must be between 0.005 and 1 m")


@dataclass
class SetupSpec:
    """Table, fixed robot arm and lighting (the paper uses two robot setups)."""

    __pydantic_config__ = _FORBID_EXTRA

    name: str = "panda_wood"
    table_urdf: str = "pybullet_data:table/table.urdf"
    table_top_m: float = 0.625
    """Height of the table top in the URDF's frame; the world origin is put on the table top."""
    table_rgba: tuple[float, float, float, float] | None = None
    robot_urdf: str = "pybullet_data:franka_panda/panda.urdf"
    robot_base_m: Vec3 = (-0.62, 0.0, 0.0)
    robot_yaw_deg: float = 0.0
    robot_joints_rad: list[float] = field(
        default_factory=lambda: [0.0, -1.2, 0.0, -2.6, 0.0, 1.6, 0.785, 0.02, 0.02]
    )
    light_direction: Vec3 = (0.4, 0.3, 1.0)
    """Direction towards the light (world frame); lighting is fixed in the world."""
    light_color: Vec3 = (1.0, 1.0, 1.0)
    ambient: float = 0.55
    diffuse: float = 0.45
    specular: float = 0.0
    shadows: bool = True
    markers: list[MarkerSpec] = field(default_factory=list)
    """ArUco markers lying on the table (scale and frame for real-style registration); ids
    unique."""
    workspace_center_m: Vec3 = (0.0, 0.0, 0.04)
    """Where the scan trajectory looks."""
    workspace_half_extent_m: tuple[float, float] = (0.3, 0.25)
    """Half size (x, y) of the area where objects are placed."""

    def __post_init__(self) -> None:
        ids = [m.id for m in self.markers]
        if len(set(ids)) != len(ids):
            raise ValueError("markers: every marker needs its own id")


@dataclass
class ScanSpec:
    """How one scan is captured: a hemispherical spiral for training plus a held-out ring."""

    __pydantic_config__ = _FORBID_EXTRA

    width: int = 320
    height: int = 240
    fov_y_deg: float = 55.0
    n_train: int = 96
    n_eval: int = 12
    radius_m: float = 0.75
    elevation_min_deg: float = 25.0
    elevation_max_deg: float = 70.0
    turns: float = 3.0
    """Number of sweeps across ``azimuth_range_deg`` (back and forth) while rising."""
    azimuth_range_deg: tuple[float, float] = (-145.0, 145.0)
    """Azimuths the camera visits (0 = +x; the robot stands at 180, so it is left out)."""
    eval_elevation_deg: float = 42.0
    eval_radius_m: float = 0.8
    near_m: float = 0.05
    far_m: float = 4.0


@dataclass
class ActionSpec:
    """One manipulation: remove an object, or move it by a relative transform."""

    __pydantic_config__ = _FORBID_EXTRA

    type: Literal["remove", "move"]
    object: str
    """Name of the object (as in ``objects``)."""
    translate_m: Vec3 = (0.0, 0.0, 0.0)
    """World-frame translation of the object's box centre (move only)."""
    yaw_deg: float = 0.0
    """Rotation about the vertical axis through the object's box centre (move only)."""


@dataclass
class SceneSpec:
    """A whole simulated scene: setup, objects, scan protocol and the actions to perform."""

    __pydantic_config__ = _FORBID_EXTRA
    name: str
    objects: list[ObjectSpec]
    actions: list[ActionSpec] = field(default_factory=list)
    setup: SetupSpec = field(default_factory=SetupSpec)
    scan: ScanSpec = field(default_factory=ScanSpec)
    kind: Literal["removal", "pick_place", "assembly", "custom"] = "custom"
    settle_s: float = 1.5
    """Simulated seconds of physics after placing objects and after each action."""

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)
