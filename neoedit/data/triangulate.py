"""Sparse points for a capture whose poses are known and whose points are not (LLFF's
``poses_bounds.npy``): SIFT features, matches, and COLMAP's point triangulation with every
pose held fixed (pycolmap). The points are what a COLMAP model would have given: the import
levels the scene on their support plane (without them, up is the cameras' mean up axis,
tilted by however far the photographer looked down: the levelled spinnerf_1's cameras look
46 deg down) and can write their depths as the sparse depth prior of ``neo train``."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np

from neoedit.data.capture import Capture
from neoedit.data.sfm import SfMConfig, match_pairs
from neoedit.errors import DataError
from neoedit.utils.progress import make_progress

OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def triangulate(capture: Capture, work: Path, cfg: SfMConfig | None = None) -> Capture:
    """``capture`` with the points its photos triangulate at their known poses (tracks and
    reprojection errors included); the database and model are written under ``work``.
    Every photo must have the same pinhole lens (LLFF's)."""
    import pycolmap

    cfg = cfg or SfMConfig()
    lens = capture.lenses[0]
    same = (lens.model, tuple(lens.params), lens.width, lens.height)
    if lens.model != "PINHOLE" or any(
        (other.model, tuple(other.params), other.width, other.height) != same
        for other in capture.lenses
    ):
        raise DataError("triangulation needs one pinhole lens for every photo")
    pycolmap.logging.minloglevel = 2
    work.mkdir(parents=True, exist_ok=True)
    pycolmap.logging.log_dir = str(work)
    database = work / "database.db"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    reader.camera_params = ",".join(f"{float(p):.10g}" for p in lens.params)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = cfg.max_image_size
    extraction.sift.max_num_features = cfg.max_features
    try:
        with make_progress(transient=True) as progress:
            task = progress.add_task(f"triangulation ({len(capture)} photos)", total=3, status="")
            pycolmap.extract_features(
                database,
                capture.image_dir,
                capture.names,
                pycolmap.CameraMode.SINGLE,
                reader,
                extraction,
                device=pycolmap.Device.cpu,
            )
            progress.advance(task)
            match_pairs(pycolmap, database, len(capture), cfg)
            progress.advance(task)
            model = _posed_model(pycolmap, database, capture)
            (work / "points").mkdir()
            with contextlib.redirect_stdout(io.StringIO()):
                model = pycolmap.triangulate_points(
                    model, database, capture.image_dir, work / "points"
                )
            progress.advance(task)
    except (RuntimeError, ValueError) as e:  # pycolmap reports its failures this way
        raise DataError(f"triangulation failed on {capture.image_dir}: {e}") from None
    return _with_points(capture, model)


def _posed_model(pycolmap, database: Path, capture: Capture):  # noqa: ANN001, ANN202
    """A reconstruction holding the database's camera and images (same ids) at the
    capture's poses, without points."""
    db = pycolmap.Database.open(database)
    try:
        cameras, images = db.read_all_cameras(), db.read_all_images()
    finally:
        db.close()
    index = {name: i for i, name in enumerate(capture.names)}
    model = pycolmap.Reconstruction()
    for camera in cameras:
        model.add_camera_with_trivial_rig(camera)
    for image in images:
        c2w = capture.camera_to_world[index[image.name]] @ OPENGL_TO_OPENCV
        w2c = np.linalg.inv(c2w)
        posed = pycolmap.Image(name=image.name, camera_id=image.camera_id, image_id=image.image_id)
        model.add_image_with_trivial_frame(posed, pycolmap.Rigid3d(w2c[:3, :4]))
    return model


def _with_points(capture: Capture, model) -> Capture:  # noqa: ANN001
    index = {image.image_id: capture.names.index(image.name) for image in model.images.values()}
    points, tracks, errors = [], [], []
    for point in model.points3D.values():
        points.append(np.asarray(point.xyz, np.float64))
        tracks.append(np.array([index[e.image_id] for e in point.track.elements], np.int64))
        errors.append(float(point.error))
    xyz = np.array(points).reshape(-1, 3)
    order = np.lexsort(xyz.T[::-1])  # one order whatever pycolmap's point ids
    return Capture(
        capture.source,
        capture.names,
        capture.image_dir,
        capture.camera_to_world,
        capture.lenses,
        xyz[order],
        [tracks[i] for i in order],
        np.array(errors)[order],
        capture.bounds,
        capture.unregistered,
    )
