"""What a training resolves from its data before it starts: the scene box and where it comes
from, the automatic sparsity weight, and the field config's data-dependent defaults (a learned
background, the room around the box)."""

from __future__ import annotations

import dataclasses

import numpy as np

from neoedit.cameras.cameras import orbit_center
from neoedit.data import SceneData
from neoedit.data.bounds import alpha_hull_box
from neoedit.errors import NeoError
from neoedit.fields.radiance import RadianceFieldConfig


def median_camera_distance(data: SceneData) -> float:
    """Median distance [m] from the cameras to the point they all look at."""
    center = orbit_center(data.cameras)
    return float(np.median(np.linalg.norm(data.cameras.camera_to_world[:, :3, 3] - center, axis=1)))


def field_config(
    cfg: RadianceFieldConfig | None, data: SceneData, box: np.ndarray
) -> RadianceFieldConfig:
    """The field config with its data-dependent defaults resolved: a learned background for
    photos (no alpha channel, or an alpha that is opaque everywhere), and a room field
    around the scene ``box`` (2,3) when most cameras look at it from outside."""
    cfg = cfg or RadianceFieldConfig()
    photos = data.alpha is None or bool((data.alpha == 255).all())
    chosen_background = cfg.learned_background
    if cfg.learned_background is None:
        cfg = dataclasses.replace(cfg, learned_background=photos)
    if cfg.room is None:
        room = photos and bool(cfg.learned_background) and not cfg.closed_bottom
        cfg = dataclasses.replace(cfg, room=room and cameras_outside(data, box) > 0.5)
    elif cfg.room:
        _check_room(cfg, chosen_background)
    return cfg


def _check_room(cfg: RadianceFieldConfig, chosen_background: bool | None) -> None:
    """Refuse a room the other options rule out, naming the one that does."""
    if cfg.closed_bottom:
        conflict = "--field.closed-bottom (the box's floor stops every ray)"  # a flag
    elif cfg.learned_background is False and chosen_background is None:
        conflict = (
            "this dataset's transparent backgrounds (RGBA images: nothing lies beyond the "
            "box, so --field.learned-background defaults to False)"
        )
    elif cfg.learned_background is False:
        conflict = "--field.learned-background False"
    else:
        return
    raise NeoError(
        f"--field.room True models what lies beyond the box, which rules out {conflict}; "
        "drop --field.room True"
    )


def cameras_outside(data: SceneData, box: np.ndarray) -> float:
    """Fraction of the cameras whose centre lies outside ``box`` (2,3). With the cameras
    inside the box (a forward-facing capture), a room behind the box took the objects from
    it (spinnerf_1: box opacity over the object 0.06 with the room, 0.28 without, 2 minutes
    of training), so the room is used only for captures that look at the box from outside
    (beer_can: +3.1 dB held out in 3 minutes, benchmarks/RESULTS.md)."""
    centres = data.cameras.camera_to_world[:, :3, 3]
    inside = ((centres >= box[0]) & (centres <= box[1])).all(-1)
    return float(1.0 - inside.mean())


def scene_box(data: SceneData, margin_m: float = 0.02) -> list[list[float]]:
    """The scene box (see :func:`scene_box_and_source`) grown by ``margin_m``."""
    return _grown(scene_box_and_source(data)[0], margin_m)


def _grown(box: np.ndarray, margin_m: float = 0.02) -> list[list[float]]:
    return [(box[0] - margin_m).tolist(), (box[1] + margin_m).tolist()]


BOX_SOURCES = {
    "dataset": "the dataset",
    "alpha": "the visual hull of the images' alpha",
    "cameras": "a cube around the cameras' look-at point (no box in the data)",
}
"""Where a scene box can come from (key -> words for ``neo info``)."""

AUTO_SPARSITY = {"dataset": 0.0, "alpha": 0.01, "cameras": 0.1}
"""Automatic ``sparsity_loss_weight`` per box source. Measured: on a loose cube around the
cameras fog explains the training views without it (0.1); on the tight visual-hull box of a
Blender-format scene 0.1 suppresses the object's own density (26.02 dB held out at 3000
steps against 26.49 at 1500 with 0.01); with a dataset box it only slows convergence."""


def scene_box_and_source(data: SceneData) -> tuple[np.ndarray, str]:
    """(2,3) scene box and where it came from (a :data:`BOX_SOURCES` key): the dataset's own
    (``scene_aabb``, instant-ngp's ``aabb_scale``) if given; else, for RGBA data with
    transparent pixels, the bounds of the silhouettes' visual hull (neoedit.data.bounds);
    otherwise a cube around the point the cameras look at, reaching out to the median camera
    distance (so it holds what an inward-looking capture sees), joined with the camera
    bounds."""
    if data.scene_aabb_m is not None:
        return np.asarray(data.scene_aabb_m, dtype=np.float64), "dataset"
    center = orbit_center(data.cameras)
    radius = median_camera_distance(data)
    if data.alpha is not None:
        cube = np.stack([center - radius, center + radius])
        hull = alpha_hull_box(data.cameras, data.alpha, data.split["train"], cube)
        if hull is not None:
            return hull, "alpha"
    cam_box = data.camera_aabb_m()
    box = np.stack(
        [np.minimum(cam_box[0], center - radius), np.maximum(cam_box[1], center + radius)]
    )
    return box, "cameras"
