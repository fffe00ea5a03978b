"""Versioned scene storage: content-addressed blobs holding tensors in full or as sparse
deltas against the version an edit started from (:mod:`.blobs`), and scene stores that keep
every version of a scene with a current pointer and a writer lock (:mod:`.store`)."""

from neoedit.storage.store import SceneStore, find_store, is_store, resolve_scene_dir

__all__ = ["SceneStore", "find_store", "is_store", "resolve_scene_dir"]
