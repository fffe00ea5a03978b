"""Pick the parser for a dataset path."""

from __future__ import annotations

from pathlib import Path

from neoedit.data.blender import load_blender
from neoedit.data.downscale import DataConfig, downscale
from neoedit.data.nerfstudio import load_nerfstudio
from neoedit.data.scene_data import SceneData
from neoedit.errors import DataError


def load_scene_data(path: Path, cfg: DataConfig | None = None) -> SceneData:
    """Load a nerfstudio (``transforms.json``) or Blender (``transforms_train.json``) dataset,
    as ``cfg`` says (downscaled, from nerfstudio's ``images_N/`` copies where they exist;
    nerfstudio frames whose image is missing dropped with a
    warning instead of refusing the dataset: Blender datasets must be complete)."""
    path = Path(path)
    cfg = cfg or DataConfig()
    cfg.check()
    try:
        data = _load(path, cfg)
        return data if data.pre_shrunk else downscale(data, cfg.factor(data.width))
    except PermissionError as e:
        raise DataError(f"cannot read the dataset {path}: {e.strerror} ({e.filename})") from None


def _load(path: Path, cfg: DataConfig) -> SceneData:
    if (path.is_file() and path.name.endswith(".json")) or (path / "transforms.json").is_file():
        return load_nerfstudio(path, skip_missing=cfg.skip_missing, factor_for=cfg.factor)
    if (path / "transforms_train.json").is_file():
        return load_blender(path)
    if not path.exists():
        raise DataError(f"dataset not found: {path}")
    raise DataError(
        f"{path}: no transforms.json (nerfstudio) or transforms_train.json (Blender) found"
    )
