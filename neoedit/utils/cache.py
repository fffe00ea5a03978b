"""Where neoedit keeps what it derives once and reuses across runs (convex parts of
simulator meshes, undistorted photos, prompt embeddings): ``$NEOEDIT_CACHE``, else
``$XDG_CACHE_HOME/neoedit``, else ``~/.cache/neoedit``. Everything in it can be deleted."""

from __future__ import annotations

import os
from pathlib import Path


def cache_dir() -> Path | None:
    """The cache root (None when no home folder is known and no variable names one)."""
    if os.environ.get("NEOEDIT_CACHE"):
        return Path(os.environ["NEOEDIT_CACHE"])
    try:
        base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    except RuntimeError:
        return None
    return Path(base) / "neoedit"
