"""Datasets on disk -> :class:`SceneData` (images, cameras, depth, instance labels, splits)."""

from neoedit.data.load import load_scene_data
from neoedit.data.scene_data import SceneData

__all__ = ["SceneData", "load_scene_data"]
