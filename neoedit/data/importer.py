"""Capture -> nerfstudio dataset: check it is one consistent piece, orient and scale it,
undistort and downscale the photos, write ``transforms.json`` (atomically, into a new
folder). ``neo import colmap|llff`` is a thin wrapper around :func:`import_capture`."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from neoedit.data.capture import Capture, Lens, read_photo
from neoedit.data.orient import Orientation, OrientConfig, look_centre, orient
from neoedit.data.pieces import PairCheck, PieceCheckConfig, find_pieces
from neoedit.data.sparse_depth import SparseDepthWriter
from neoedit.errors import DataError
from neoedit.utils.io import atomic_directory, atomic_write_json
from neoedit.utils.options import at_least
from neoedit.utils.progress import track

PIECE_CHOICES = ("check", "largest", "all")


@dataclass
class ImportConfig:
    max_width: int | None = at_least(16)
    """Downscale the photos to at most this width in pixels (aspect kept); None keeps them."""
    piece: str = "check"
    """'check': stop with an explanation when the model is broken into pieces; 'largest':
    import the largest consistent piece; 'all': import every photo anyway; or a piece
    number (1 = the first in name order)."""
    holdout_every: int = 8
    """Every n-th photo (in name order) is held out for evaluation."""
    sparse_depth: bool = True
    """Write a sparse depth image per photo (``depth/*.png``) from the model's 3D points, a
    depth prior for ``neo train`` where the photos have no depth (COLMAP models only; LLFF
    has no points)."""
    sparse_depth_min_track: int = 3
    """Only points observed by at least this many imported photos go into the depth images
    (two-view points are the noisiest)."""
    sparse_depth_max_error_px: float = 2.0
    """...and whose mean reprojection error in the model is at most this many pixels."""
    orient: OrientConfig = field(default_factory=OrientConfig)
    pieces: PieceCheckConfig = field(default_factory=PieceCheckConfig)

    def check(self) -> None:
        """DataError naming the first option out of range (before any photo is read)."""
        if self.max_width is not None and self.max_width < 16:
            raise DataError(f"--max-width must be at least 16 px, got {self.max_width}")
        if not self.sparse_depth_max_error_px > 0:
            raise DataError(
                "--sparse-depth-max-error-px must be positive, got "
                f"{self.sparse_depth_max_error_px}"
            )
        if self.sparse_depth_min_track < 2:
            raise DataError(
                f"--sparse-depth-min-track must be >= 2, got {self.sparse_depth_min_track}"
            )
        if self.holdout_every < 2:
            raise DataError(f"--holdout-every must be >= 2, got {self.holdout_every}")
        if self.piece not in PIECE_CHOICES and not (self.piece.isdigit() and int(self.piece) >= 1):
            raise DataError(
                f"--piece must be one of {', '.join(PIECE_CHOICES)} or a piece number, got "
                f"{self.piece!r}"
            )
        self.pieces.check()
        for name in ("scale", "camera_distance_m", "aruco_size_m"):
            value = getattr(self.orient, name)
            if value is not None and not (0 < value < float("inf")):
                raise DataError(
                    f"--orient.{name.replace('_', '-')} must be a positive number, got {value}"
                )


@dataclass
class ImportReport:
    out: Path
    frames: int
    size: tuple[int, int]
    pieces: list[tuple[str, str, int]]
    """(first name, last name, photos) of every consistent piece."""
    chosen: str
    orientation: Orientation
    checks: list[PairCheck]
    """Every consecutive pair examined with feature matches (:mod:`neoedit.data.pieces`)."""
    doubts: list[str] = field(default_factory=list)
    """'first -> second: evidence' of the pairs whose matches disagree with the model's
    poses, too weakly to call a break: imported, with a warning."""
    sparse_depth: dict | None = None
    """What the sparse depth holds (points, median pixels per photo, unit), None if none."""


def _choose(
    capture: Capture, pieces: list[np.ndarray], choice: str, breaks: list[PairCheck]
) -> tuple[np.ndarray, str]:
    spans = [f"{capture.names[p[0]]}..{capture.names[p[-1]]} ({len(p)} photos)" for p in pieces]
    if choice == "all" or len(pieces) == 1:
        return np.arange(len(capture)), "all photos" + (" (one piece)" if len(pieces) == 1 else "")
    if choice == "largest":
        k = int(np.argmax([len(p) for p in pieces]))
        return pieces[k], f"piece {k + 1} of {len(pieces)}: {spans[k]}"
    if choice.isdigit() and 1 <= int(choice) <= len(pieces):
        k = int(choice) - 1
        return pieces[k], f"piece {k + 1} of {len(pieces)}: {spans[k]}"
    listing = "\n".join(f"  piece {k + 1}: {s}" for k, s in enumerate(spans))
    evidence = "\n".join(f"  {c.describe(capture.names)}" for c in breaks)
    if choice == "check":
        raise DataError(
            f"{capture.source}: this model is broken into {len(pieces)} inconsistent pieces "
            "(consecutive photos match each other but not under the model's poses, so a field "
            f"trained on all of them would be blurry):\n{listing}\nthe evidence, at each break:"
            f"\n{evidence}\nre-run structure-from-motion "
            "(neo process), or import one piece with --piece largest or --piece N "
            "(--piece all imports everything anyway)"
        )
    raise DataError(
        f"--piece must be one of {', '.join(PIECE_CHOICES)} or 1..{len(pieces)}, got {choice!r}"
    )


def undistort_lens(lens: Lens, scale: float) -> tuple[np.ndarray, Any, Any, tuple[int, int]]:
    """New pinhole K (COLMAP pixel convention) at ``scale``, remap tables and output size.
    The undistorted image keeps only valid pixels (no black border)."""
    import cv2

    w, h = lens.width, lens.height
    k_cv = lens.matrix().copy()
    k_cv[:2, 2] -= 0.5  # OpenCV's pixel centres sit on integers, COLMAP's on +0.5
    dist = lens.distortion()
    new_k = (
        cv2.getOptimalNewCameraMatrix(k_cv, dist, (w, h), 0.0, (w, h))[0]
        if lens.distorted
        else k_cv
    )
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    out_k = new_k.copy()
    out_k[0] *= size[0] / w
    out_k[1] *= size[1] / h
    out_k[:2, 2] = (new_k[:2, 2] + 0.5) * np.array([size[0] / w, size[1] / h])
    if not lens.distorted:
        return out_k, None, None, size
    map1, map2 = cv2.initUndistortRectifyMap(k_cv, dist, None, new_k, (w, h), cv2.CV_32FC1)
    return out_k, map1, map2, size


def _convert(capture: Capture, i: int, scale: float, maps: dict) -> tuple[np.ndarray, np.ndarray]:
    import cv2

    lens = capture.lenses[i]
    key = (lens.model, tuple(lens.params), lens.width, lens.height)
    if key not in maps:
        maps[key] = undistort_lens(lens, scale)
    k, map1, map2, size = maps[key]
    image = read_photo(capture.image_dir / capture.names[i])
    if image.shape[:2] != (lens.height, lens.width):
        raise DataError(
            f"{capture.names[i]} is {image.shape[1]}x{image.shape[0]} but its camera says "
            f"{lens.width}x{lens.height}"
        )
    if map1 is not None:
        image = cv2.remap(image, map1, map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    if size != (lens.width, lens.height):
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    return image, k


def import_capture(
    capture: Capture,
    out: Path,
    cfg: ImportConfig,
    overwrite: bool = False,
    extras: Callable[[Path], None] | None = None,
) -> ImportReport:
    """Write ``capture`` as a nerfstudio dataset in the new folder ``out``; ``extras(folder)``
    adds files to it before it is published."""
    import cv2

    sizes = {(lens.width, lens.height) for lens in capture.lenses}
    if len(sizes) != 1:
        raise DataError(
            f"{capture.source}: photos of several sizes {sorted(sizes)}; neoedit needs one size"
        )
    cfg.check()
    pieces, checks = find_pieces(capture, cfg.pieces)
    breaks = [c for c in checks if c.is_break(cfg.pieces)]
    index, chosen = _choose(capture, pieces, cfg.piece, breaks)
    doubts = [c.describe(capture.names) for c in checks if c.verdict(cfg.pieces) == "doubtful"]
    part = capture.subset(index)
    output_names = _output_names(part)
    frame = orient(part, cfg.orient)
    width = next(iter(sizes))[0]
    scale = min(1.0, cfg.max_width / width) if cfg.max_width else 1.0
    maps: dict = {}
    frames: list[dict] = []
    train: list[str] = []
    test: list[str] = []
    depth = _depth_writer(capture, index, frame, cfg) if cfg.sparse_depth else None
    with atomic_directory(out, overwrite=overwrite, kind="dataset") as tmp:
        (tmp / "images").mkdir()
        for j in track(range(len(part)), "undistorting photos"):
            image, k = _convert(part, j, scale, maps)
            name = output_names[j]
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            if not cv2.imwrite(str(tmp / name), image):
                raise DataError(f"cannot write {out / name}")
            c2w = frame.transform @ part.camera_to_world[j]
            c2w[:3, :3] /= frame.scale
            frames.append(_frame_entry(name, c2w, k, image.shape))
            if depth is not None:
                rel = "depth/" + name.removeprefix("images/")
                depth.write(tmp, rel, j, c2w, k, (image.shape[1], image.shape[0]))
                frames[-1]["depth_file_path"] = rel
            (test if j % cfg.holdout_every == 0 else train).append(name)
        meta = {
            "camera_model": "OPENCV",
            "frames": frames,
            "train_filenames": train,
            "test_filenames": test,
            "scene_aabb": np.round(frame.aabb_m, 5).tolist(),
            "neoedit_import": {
                "source": str(capture.source),
                "photos": len(capture),
                "imported": chosen,
                "pieces": [[part_span(capture, p), len(p)] for p in pieces],
                "orientation": frame.to_dict(),
            },
        }
        if depth is not None and sum(depth.pixels) == 0:  # no point survived: no depth
            shutil.rmtree(tmp / "depth", ignore_errors=True)
            for f in frames:
                f.pop("depth_file_path", None)
        elif depth is not None:
            meta["depth_unit_scale_factor"] = depth.unit
            meta["neoedit_import"]["sparse_depth"] = depth.summary()
        atomic_write_json(tmp / "transforms.json", meta)
        if extras is not None:
            extras(tmp)
    spans = [(capture.names[p[0]], capture.names[p[-1]], len(p)) for p in pieces]
    h, w = frames[0]["h"], frames[0]["w"]
    summary = meta["neoedit_import"].get("sparse_depth")
    return ImportReport(
        Path(out), len(frames), (w, h), spans, chosen, frame, checks, doubts, summary
    )


def _output_names(part: Capture) -> list[str]:
    """The dataset's image paths of the photos to import (at least 3, each PNG unique)."""
    if len(part) < 3:
        raise DataError(f"only {len(part)} photos to import; need at least 3")
    output_names = [f"images/{Path(n).with_suffix('.png').as_posix()}" for n in part.names]
    if len(set(output_names)) != len(output_names):
        raise DataError(
            f"{part.source}: two photos would both be written as the same PNG (same name "
            "with different suffixes); rename one"
        )
    return output_names


def _depth_writer(
    capture: Capture, index: np.ndarray, frame: Orientation, cfg: ImportConfig
) -> SparseDepthWriter | None:
    """The sparse depth of the imported photos ``index``, from the points whose whole track
    lies among them (a point also seen by another piece was triangulated from poses that
    disagree with this one), in the dataset's frame; None without points."""
    part = capture.subset(index, whole_tracks=True)
    if not len(part.points):
        return None
    rot, shift = frame.transform[:3, :3], frame.transform[:3, 3]
    centres = part.centres @ rot.T + shift
    look = look_centre(part) @ rot.T + shift
    return SparseDepthWriter(
        part.points @ rot.T + shift,
        part.point_tracks,
        centres,
        np.asarray(frame.aabb_m),
        part.point_errors,
        cfg.sparse_depth_min_track,
        cfg.sparse_depth_max_error_px,
        # the trainer's automatic near plane: nothing nearer can be a surface
        min_depth=0.25 * float(np.median(np.linalg.norm(centres - look, axis=1))),
    )


def part_span(capture: Capture, index: np.ndarray) -> str:
    return f"{capture.names[index[0]]}..{capture.names[index[-1]]}"


def _frame_entry(name: str, c2w: np.ndarray, k: np.ndarray, shape: tuple) -> dict:
    return {
        "file_path": name,
        "transform_matrix": np.round(c2w, 9).tolist(),
        "fl_x": float(k[0, 0]),
        "fl_y": float(k[1, 1]),
        "cx": float(k[0, 2]),
        "cy": float(k[1, 2]),
        "w": int(shape[1]),
        "h": int(shape[0]),
    }
