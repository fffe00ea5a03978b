"""``neo import colmap|llff``: a user's capture (COLMAP model or LLFF poses) -> a
nerfstudio dataset that ``neo info`` and ``neo train`` read."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Union

import numpy as np
import tyro
from rich.console import Console
from rich.markup import escape

from neoedit.data.capture import Capture
from neoedit.data.importer import ImportConfig, ImportReport, import_capture
from neoedit.data.orient import MIN_PLANE_POINTS, OrientConfig
from neoedit.data.pieces import PieceCheckConfig
from neoedit.data.sfm import SfMConfig
from neoedit.errors import DataError, NeoError
from neoedit.utils.io import check_writable_output, work_directory


@dataclass
class _ImportBase:
    src: tyro.conf.Positional[Path]
    """The capture: a COLMAP project (sparse/0 + images), a model folder, or an LLFF folder
    (poses_bounds.npy + images)."""
    out: Path
    """New dataset folder (transforms.json + images/)."""
    images: Path | None = None
    """Photo folder when it is not 'images' beside the model."""
    max_width: int | None = None
    """Downscale the photos to at most this width in pixels (aspect kept); default: keep."""
    piece: str = "check"
    """'check': stop with an explanation when the model is broken into inconsistent pieces;
    'largest': import the largest consistent piece; 'all': every photo anyway; or a piece
    number (1 = the first in name order)."""
    holdout_every: int = 8
    """Every n-th photo (in name order) is held out for evaluation."""
    sparse_depth: bool = True
    """Write each photo's sparse depth from the model's 3D points (depth/*.png), a depth prior
    for neo train (on beer_can it gives the floor and the can their surfaces)."""
    sparse_depth_min_track: int = 3
    """Only points seen by at least this many imported photos go into the depth images."""
    sparse_depth_max_error_px: float = 2.0
    """...and whose mean reprojection error in the model is at most this [px]."""
    orient: OrientConfig = field(default_factory=OrientConfig)
    check: PieceCheckConfig = field(default_factory=PieceCheckConfig)
    overwrite: bool = False
    """Replace ``out`` if it is a dataset an earlier import wrote."""

    def read(self) -> Capture:
        raise NotImplementedError

    def run(self) -> None:
        cfg = import_config(self, self.check)
        cfg.check()
        check_writable_output(
            self.out, [self.src, self.images], kind="dataset", overwrite=self.overwrite
        )
        report = import_capture(self.read(), self.out, cfg, overwrite=self.overwrite)
        print_report(report)


@dataclass
class ImportColmapCommand(_ImportBase):
    """Import a COLMAP sparse model (binary or text): undistort, orient z-up, scale, write
    a nerfstudio dataset."""

    def read(self) -> Capture:
        from neoedit.data.colmap import read_colmap

        return read_colmap(self.src, self.images)


@dataclass
class ImportLLFFCommand(_ImportBase):
    """Import an LLFF capture (poses_bounds.npy): triangulate sparse points at its poses,
    orient z-up, scale, write a nerfstudio dataset."""

    triangulate: bool = True
    """Triangulate sparse points at the known poses (SIFT features and matches, COLMAP's
    point triangulation; 25 s for spinnerf_1's 100 photos) and level the scene on their
    support plane. Without them up is the cameras' mean up, tilted back by how far the
    photos look down, and yaw-only query boxes fit the tilted objects badly (spinnerf_1:
    "box" matched nothing; levelled: found, IoU 0.75 with the masks' box). When it fails
    or gives too few points for a plane, the import goes on with the cameras' mean up and
    says so."""
    sparse_depth: bool = False
    """Write each photo's sparse depth from the triangulated points (depth/*.png). Off for
    LLFF: from a forward-facing capture's narrow baseline they are too noisy to help
    (spinnerf_1, 5 min with the room, runs of two sessions: removal 18.80 -> 19.55 dB with
    them at 926 steps, 19.22 -> 21.04 without at 1,369; benchmarks/RESULTS.md)."""

    def read(self) -> Capture:
        from neoedit.data.llff import read_llff

        capture = read_llff(self.src, self.images)
        if not self.triangulate:
            return capture
        from neoedit.data.triangulate import triangulate

        try:
            with work_directory(self.out) as work:
                capture = triangulate(capture, work)
        except DataError as e:
            _cameras_up(str(e), " (--no-triangulate skips the attempt)")
            return capture
        if len(capture.points) < MIN_PLANE_POINTS:
            _cameras_up(
                f"triangulation gave {len(capture.points)} sparse points, too few for a "
                f"support plane (< {MIN_PLANE_POINTS})"
            )
        else:
            Console().print(f"triangulation: {len(capture.points)} sparse points")
        return capture


def _cameras_up(why: str, hint: str = "") -> None:
    """Warn that an LLFF import goes on levelled by the cameras' mean up, and why."""
    Console(stderr=True).print(
        f"[yellow]warning:[/] {escape(why)}; up is the cameras' mean up{escape(hint)}",
        highlight=False,
    )


ImportCommands = Annotated[
    Union[  # noqa: UP007 (tyro reads the Union)
        Annotated[ImportColmapCommand, tyro.conf.subcommand("colmap")],
        Annotated[ImportLLFFCommand, tyro.conf.subcommand("llff")],
    ],
    tyro.conf.subcommand(
        "import", description="A COLMAP model or LLFF capture -> a nerfstudio dataset."
    ),
]


def import_config(
    cmd: _ImportBase | ProcessCommand, pieces: PieceCheckConfig | None = None
) -> ImportConfig:
    """The import options of a command (``neo import`` also sets the piece check)."""
    return ImportConfig(
        max_width=cmd.max_width,
        piece=cmd.piece,
        holdout_every=cmd.holdout_every,
        sparse_depth=cmd.sparse_depth,
        sparse_depth_min_track=cmd.sparse_depth_min_track,
        sparse_depth_max_error_px=cmd.sparse_depth_max_error_px,
        orient=cmd.orient,
        pieces=pieces or PieceCheckConfig(),
    )


def print_report(report: ImportReport) -> None:
    c = Console()
    o = report.orientation
    c.print(
        f"[bold]{report.out}[/]: {report.frames} frames of {report.size[0]}x{report.size[1]} "
        f"({report.chosen})"
    )
    if len(report.pieces) > 1:
        c.print(f"[yellow]the model is in {len(report.pieces)} inconsistent pieces:[/]")
        for first, last, n in report.pieces:
            c.print(f"  {first}..{last}: {n} photos")
    for doubt in report.doubts:
        Console(stderr=True).print(
            f"[yellow]warning:[/] {escape(doubt)}; too weak to call the model broken "
            "(imported); if renders are blurry near these photos, check their poses",
            highlight=False,
        )
    c.print(f"up: {o.up_source}; scale x{o.scale:.4g} ({o.scale_source})")
    if o.scale_source.startswith("ASSUMED"):
        c.print(
            "[yellow]the scale is assumed[/]: give --orient.camera-distance-m (or "
            "--orient.scale) for metric edits and grasps"
        )
    for note in o.notes:
        c.print(f"[yellow]{escape(str(note))}[/]")
    box = o.aabb_m.round(3).tolist()
    c.print(f"scene box (m): {box}")
    if report.sparse_depth:
        d = report.sparse_depth
        c.print(
            f"sparse depth: {d['points']} points, {d['pixels_per_photo_median']} pixels a photo "
            "(median); neo train adds a depth loss on them"
        )
    else:
        c.print("sparse depth: none (no usable points, or --no-sparse-depth)")


@dataclass
class ProcessCommand:
    """Photos or a video -> structure-from-motion on the CPU (pycolmap) -> a nerfstudio
    dataset (oriented, scaled, undistorted; the COLMAP model kept in DATA/colmap)."""

    src: tyro.conf.Positional[Path]
    """A folder of photos (in capture order) or a video file."""
    out: Path
    """New dataset folder."""
    sfm: SfMConfig = field(default_factory=SfMConfig)
    max_width: int | None = None
    """Downscale the photos to at most this width in pixels; default: keep."""
    piece: str = "check"
    """As for ``neo import``: what to do when the model is inconsistent."""
    holdout_every: int = 8
    sparse_depth: bool = True
    """Write each photo's sparse depth from the model's 3D points (depth/*.png), a depth prior
    for neo train (on beer_can it gives the floor and the can their surfaces)."""
    sparse_depth_min_track: int = 3
    """Only points seen by at least this many imported photos go into the depth images."""
    sparse_depth_max_error_px: float = 2.0
    """...and whose mean reprojection error in the model is at most this [px]."""
    orient: OrientConfig = field(default_factory=OrientConfig)
    overwrite: bool = False

    def run(self) -> None:
        import shutil
        import time

        from neoedit.data.colmap import read_colmap
        from neoedit.data.sfm import VIDEO_SUFFIXES, run_sfm, video_frames

        src = Path(self.src)
        if not src.exists():
            raise NeoError(f"not found: {src}")
        is_video = src.is_file() and src.suffix in VIDEO_SUFFIXES
        if src.is_file() and not is_video:
            raise NeoError(f"{src}: not a photo folder or a video ({', '.join(VIDEO_SUFFIXES)})")
        cfg = import_config(self)
        cfg.check()
        self.sfm.check()
        check_writable_output(self.out, [src], kind="dataset", overwrite=self.overwrite)
        with work_directory(self.out) as work:
            t0 = time.perf_counter()
            images = src
            if is_video:
                images = work / "frames"
                video_frames(src, images, self.sfm.video_frames)
            result = run_sfm(images, work, self.sfm)
            seconds = time.perf_counter() - t0
            if len(result.tried) > 1:  # the first mapper failed or its model broke: say so
                Console().print("mappers tried: " + "; ".join(result.tried))
            Console().print(
                f"structure-from-motion ({result.mapper} mapper): {result.registered} of "
                f"{result.total} photos registered ({result.models} model"
                f"{'s' if result.models > 1 else ''}) in {seconds:.0f} s"
            )
            # named by the photos in messages (the model lives in a temporary folder)
            capture = dataclasses.replace(read_colmap(result.model, images), source=src)

            def keep_model(folder: Path) -> None:
                shutil.copytree(result.model, folder / "colmap" / "sparse" / "0")

            report = import_capture(capture, self.out, cfg, self.overwrite, extras=keep_model)
        print_report(report)


@dataclass
class RegisterCommand:
    """Move a later scan (POST) into an earlier scan's (PRE) frame with the ArUco markers
    both see; writes a copy of POST with the new camera poses."""

    pre: tyro.conf.Positional[Path]
    """The reference dataset."""
    post: tyro.conf.Positional[Path]
    """The dataset to align (e.g. the scan after a manipulation)."""
    out: Path
    """New dataset folder: POST in PRE's frame."""
    aruco_dict: str = "4X4_50"
    overwrite: bool = False

    def run(self) -> None:
        from neoedit.data.register import register_scans, write_registered

        check_writable_output(
            self.out, [self.pre, self.post], kind="dataset", overwrite=self.overwrite
        )
        reg = register_scans(self.pre, self.post, self.aruco_dict)
        write_registered(self.pre, self.post, reg, self.out, self.overwrite)
        t = reg.transform[:3, 3]
        Console().print(
            f"[bold]{self.out}[/]: {self.post} in the frame of {self.pre} (markers {reg.markers}); "
            f"scale x{reg.scale:.5f}, rotation {reg.rotation_deg:.2f} deg, translation "
            f"{np.round(t, 4).tolist()}; corner residual {1000 * reg.rms_m:.2f} mm"
        )
