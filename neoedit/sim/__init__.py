"""NEO-Sim: PyBullet tabletop scans before and after manipulation, with exact ground truth."""

from neoedit.sim.spec import ActionSpec, ObjectSpec, ScanSpec, SceneSpec, SetupSpec
from neoedit.sim.specfile import load_scene_spec

__all__ = ["ActionSpec", "ObjectSpec", "ScanSpec", "SceneSpec", "SetupSpec", "load_scene_spec"]
