"""Structure-from-motion on the CPU with ``pycolmap``: photos (or frames of a video) ->
a COLMAP sparse model, for ``neo process``.

Stages: SIFT features (one shared SIMPLE_RADIAL camera by default), matching (sequential
with an overlap window for video frames and long photo series, exhaustive for small
sets), incremental mapping; the model with the most registered images is kept.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from neoedit.data.capture import LENS_MODELS
from neoedit.data.colmap import IMAGE_SUFFIXES
from neoedit.errors import DataError
from neoedit.utils.progress import make_progress

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm", ".MP4", ".MOV")
MATCHERS = ("auto", "sequential", "exhaustive")


@dataclass
class SfMConfig:
    matcher: str = "auto"
    """'sequential' (each image with its ``overlap`` successors: videos, walks), 'exhaustive'
    (every pair: small unordered sets) or 'auto' (exhaustive up to 40 photos)."""
    overlap: int = 12
    """Successors each image is matched with in sequential matching."""
    max_image_size: int = 1024
    """Photos are read at most this large (longest side) for features."""
    max_features: int = 4096
    camera_model: str = "SIMPLE_RADIAL"
    """COLMAP camera model shared by all photos (one physical camera)."""
    min_registered: float = 0.5
    """Fail when fewer than this share of the photos register in the largest model."""
    video_frames: int = 100
    """Frames sampled evenly from a video."""
    seed: int = field(default=0, metadata={"max": 2**31 - 1})
    """COLMAP's random seed (a C int: at most 2^31 - 1)."""


@dataclass
class SfMResult:
    model: Path
    images: Path
    registered: int
    total: int
    models: int
    """How many separate models the mapper made (more than one: the photos fell apart)."""


def video_frames(video: Path, out: Path, count: int) -> int:
    """Write ``count`` evenly spaced frames of ``video`` as ``out/NNNNN.jpg``."""
    import cv2

    cap = cv2.VideoCapture(str(video))
    total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    if not cap.isOpened() or total <= 0:
        raise DataError(f"cannot read video {video}")
    out.mkdir(parents=True, exist_ok=True)
    step = max(total / max(count, 1), 1.0)
    wanted = sorted({int(i * step) for i in range(min(count, total))})
    written = 0
    for k, index in enumerate(wanted):
        cap.set(cv2.CAP_PROP_POS_FRAMES, index)
        ok, frame = cap.read()
        if ok and cv2.imwrite(str(out / f"{k:05d}.jpg"), frame, [cv2.IMWRITE_JPEG_QUALITY, 95]):
            written += 1
    cap.release()
    if written < 3:
        raise DataError(f"{video}: only {written} frames could be read")
    return written


def list_images(folder: Path) -> list[str]:
    return sorted(p.name for p in Path(folder).iterdir() if p.suffix in IMAGE_SUFFIXES)


def run_sfm(images: Path, work: Path, cfg: SfMConfig) -> SfMResult:
    """Features, matches and incremental mapping of the photos in ``images``; the COLMAP
    database and models are written under ``work``."""
    import pycolmap

    names = list_images(images)
    if len(names) < 3:
        raise DataError(f"{images}: {len(names)} photos; structure-from-motion needs at least 3")
    if cfg.camera_model not in LENS_MODELS:
        raise DataError(
            f"--sfm.camera-model must be one of {', '.join(LENS_MODELS)}, got {cfg.camera_model!r}"
        )
    if cfg.matcher not in MATCHERS:
        raise DataError(f"--sfm.matcher must be one of {', '.join(MATCHERS)}, got {cfg.matcher!r}")
    pycolmap.logging.minloglevel = 2  # our progress instead of COLMAP's log lines
    database = work / "database.db"
    work.mkdir(parents=True, exist_ok=True)
    pycolmap.logging.log_dir = str(work)  # its log files (default: /tmp) go with the work
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = cfg.camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = cfg.max_image_size
    extraction.sift.max_num_features = cfg.max_features
    sequential = is_sequential(cfg, len(names))
    stages: list[tuple[str, Callable[[], object]]] = [
        (
            f"features ({len(names)} photos)",
            lambda: pycolmap.extract_features(
                database,
                images,
                names,
                pycolmap.CameraMode.SINGLE,
                reader,
                extraction,
                device=pycolmap.Device.cpu,
            ),
        ),
        (
            "matching ("
            + (f"sequential, overlap {cfg.overlap}" if sequential else "exhaustive")
            + ")",
            lambda: match_pairs(pycolmap, database, len(names), cfg),
        ),
    ]
    try:
        with make_progress(transient=True) as progress:
            for label, run in stages:
                task = progress.add_task(label, total=1, status="")
                run()
                progress.advance(task)
            task = progress.add_task("mapping", total=len(names), status="")
            options = pycolmap.IncrementalPipelineOptions()
            options.random_seed = cfg.seed
            models = pycolmap.incremental_mapping(
                database,
                images,
                work / "sparse",
                options,
                next_image_callback=lambda: progress.advance(task),
            )
    except (RuntimeError, ValueError) as e:  # pycolmap reports its failures this way
        raise DataError(f"structure-from-motion failed on {images}: {e}") from None
    return _largest(models, work, images, len(names), cfg)


def is_sequential(cfg: SfMConfig, photos: int) -> bool:
    return cfg.matcher == "sequential" or (cfg.matcher == "auto" and photos > 40)


def match_pairs(pycolmap, database: Path, photos: int, cfg: SfMConfig) -> None:  # noqa: ANN001
    """Feature matches between the photos of ``database``: sequential (neighbours in name
    order) or exhaustive, as ``cfg.matcher`` says ('auto': sequential beyond 40 photos)."""
    if is_sequential(cfg, photos):
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = cfg.overlap
        pairing.loop_detection = False  # needs a vocabulary tree (a download)
        pycolmap.match_sequential(database, pairing_options=pairing, device=pycolmap.Device.cpu)
    else:
        pycolmap.match_exhaustive(database, device=pycolmap.Device.cpu)


def _largest(models: dict, work: Path, images: Path, total: int, cfg: SfMConfig) -> SfMResult:
    if not models:
        raise DataError(
            f"structure-from-motion registered none of the {total} photos of {images} (too "
            "little overlap or texture between them?)"
        )
    key = max(models, key=lambda k: models[k].num_reg_images())
    rec = models[key]
    registered = int(rec.num_reg_images())
    if registered < cfg.min_registered * total:
        raise DataError(
            f"structure-from-motion registered only {registered} of {total} photos in its "
            f"largest model ({len(models)} models); take more overlapping photos or use "
            "--sfm.matcher exhaustive"
        )
    model = work / "model"
    model.mkdir(parents=True, exist_ok=True)
    rec.write_binary(str(model))
    return SfMResult(model, images, registered, total, len(models))
