"""Structure-from-motion on the CPU with ``pycolmap``: photos (or frames of a video) ->
a COLMAP sparse model, for ``neo process``.

Stages: SIFT features (one shared SIMPLE_RADIAL camera by default), matching (sequential
with an overlap window for video frames and long photo series, exhaustive for small
sets), mapping; the model with the most registered images is kept.

Mapping is global (GLOMAP's rotation averaging and global positioning, built into COLMAP)
or incremental (COLMAP's image-by-image mapper). On bonsai (292 photos, 2 cores) the global
mapper took 5.5 min and gave a clean camera ring (0.13-0.23 px between neighbours) where the
incremental one took 22 min and bent the ring out of shape (consecutive photos up to 50x the
median step apart; 2.6 px at such a step), which the consistency check, blind to scale,
passes. On beer_can it is the other way round (global: 2-4 consistent pieces, the
largest 29 photos; incremental: 2, the largest 60). So ``mapper="auto"`` maps globally,
checks the model with the importer's consistency check and, when that finds a break, maps
incrementally too and keeps the model whose largest consistent piece is larger.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from neoedit.data.capture import LENS_MODELS
from neoedit.data.colmap import IMAGE_SUFFIXES, read_colmap
from neoedit.errors import DataError, NeoError
from neoedit.utils.progress import make_progress
from neoedit.utils.threads import thread_budget

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm", ".MP4", ".MOV")
MATCHERS = ("auto", "sequential", "exhaustive")
MAPPERS = ("auto", "global", "incremental")


@dataclass
class SfMConfig:
    matcher: str = "auto"
    """'sequential' (each image with its ``overlap`` successors: videos, walks), 'exhaustive'
    (every pair: small unordered sets) or 'auto' (exhaustive up to 40 photos)."""
    overlap: int = 12
    """Successors each image is matched with in sequential matching."""
    mapper: str = "auto"
    """'global' (rotation averaging + global positioning: fast at hundreds of photos),
    'incremental' (image by image) or 'auto' (global; incremental too when the global mapper
    fails, registers too few photos or its model breaks into inconsistent pieces, keeping
    the model with the larger consistent piece)."""
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

    def check(self) -> None:
        """The named choices, before any work (numbers: :func:`check_options`)."""
        for flag, value, allowed in (
            ("--sfm.camera-model", self.camera_model, LENS_MODELS),
            ("--sfm.matcher", self.matcher, MATCHERS),
            ("--sfm.mapper", self.mapper, MAPPERS),
        ):
            if value not in allowed:
                raise DataError(f"{flag} must be one of {', '.join(allowed)}, got {value!r}")


@dataclass
class SfMResult:
    model: Path
    images: Path
    registered: int
    total: int
    models: int
    """How many separate models the mapper made (more than one: the photos fell apart)."""
    mapper: str
    """The mapper whose model this is ('global' or 'incremental')."""
    tried: list[str] = field(default_factory=list)
    """One line per mapper run: its model's registered photos and consistent pieces."""


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
    """Features, matches and mapping (``cfg.mapper``) of the photos in ``images``; the COLMAP
    database and models are written under ``work``."""
    import pycolmap

    names = list_images(images)
    if len(names) < 3:
        raise DataError(f"{images}: {len(names)} photos; structure-from-motion needs at least 3")
    cfg.check()
    pycolmap.logging.minloglevel = 2  # our progress instead of COLMAP's log lines
    database = work / "database.db"
    work.mkdir(parents=True, exist_ok=True)
    pycolmap.logging.log_dir = str(work)  # its log files (default: /tmp) go with the work
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = cfg.camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = cfg.max_image_size
    extraction.sift.max_num_features = cfg.max_features
    extraction.num_threads = thread_budget()
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
            return _map(pycolmap, database, images, work, cfg, progress, len(names))
    except (RuntimeError, ValueError) as e:  # pycolmap reports its failures this way
        raise DataError(f"structure-from-motion failed on {images}: {e}") from None


def _map(
    pycolmap: Any, database: Path, images: Path, work: Path, cfg: SfMConfig, progress: Any,
    total: int,
) -> SfMResult:  # fmt: skip
    """Run the mapper(s) ``cfg.mapper`` names; the best model, written to
    ``work/model_<mapper>``. With two, the second runs only when the first fails, registers
    too few photos or breaks into inconsistent pieces."""
    order = ["global", "incremental"] if cfg.mapper == "auto" else [cfg.mapper]
    compare = len(order) > 1
    best: tuple[tuple, SfMResult] | None = None
    tried: list[str] = []
    for mapper in order:
        try:
            models = _run_mapper(pycolmap, mapper, database, images, work, cfg, progress, total)
        except (RuntimeError, ValueError) as e:  # COLMAP's checks failed on this view graph
            if not compare:
                raise
            tried.append(
                f"{mapper}: failed ({(str(e).strip().splitlines() or [type(e).__name__])[0]})"
            )
            continue
        result = _largest(models, work / f"model_{mapper}", images, total, mapper)
        if result is None:
            tried.append(f"{mapper}: no model")
            continue
        enough = result.registered >= cfg.min_registered * total
        try:
            pieces = _consistent_pieces(result, progress) if compare else None
        except (NeoError, RuntimeError, ValueError) as e:  # a model the check cannot read
            tried.append(f"{mapper}: its model could not be checked ({e})")
            continue
        tried.append(_describe(result, pieces))
        largest = max(len(p) for p in pieces) if pieces is not None else 0
        score = (enough, largest, result.registered)
        if best is None or score > best[0]:
            best = (score, result)
        if enough and (pieces is None or len(pieces) == 1):
            break  # one consistent model: no need for the other mapper
    said = f" (mappers tried: {'; '.join(tried)})" if compare else ""
    if best is None:
        raise DataError(
            f"structure-from-motion registered none of the {total} photos of {images} (too "
            f"little overlap or texture between them?){said}"
        )
    result = best[1]
    if result.registered < cfg.min_registered * total:
        other = {"global": " or --sfm.mapper incremental", "incremental": " or --sfm.mapper global"}
        raise DataError(
            f"structure-from-motion registered only {result.registered} of {total} photos in "
            f"its largest model ({result.models} model{'s' if result.models > 1 else ''})"
            f"{said}; take more overlapping photos or use --sfm.matcher exhaustive"
            + other.get(cfg.mapper, "")
        )
    return dataclasses.replace(result, tried=tried)


def _describe(result: SfMResult, pieces: list | None) -> str:
    """'global: 71 of 71 photos registered, broken into 4 pieces' (a line of ``tried``)."""
    line = f"{result.mapper}: {result.registered} of {result.total} photos registered"
    if pieces is None:
        return line
    return line + (
        ", one consistent piece" if len(pieces) == 1 else f", broken into {len(pieces)} pieces"
    )


def _run_mapper(
    pycolmap: Any, mapper: str, database: Path, images: Path, work: Path, cfg: SfMConfig,
    progress: Any, total: int,
) -> dict:  # fmt: skip
    out = work / f"sparse_{mapper}"
    out.mkdir(parents=True, exist_ok=True)
    if mapper == "global":
        task = progress.add_task("mapping (global)", total=1, status="")
        options = pycolmap.GlobalPipelineOptions()
        options.random_seed = cfg.seed
        options.num_threads = thread_budget()
        models = pycolmap.global_mapping(database, images, out, options)
        progress.advance(task)
        return models
    task = progress.add_task("mapping (incremental)", total=total, status="")
    options = pycolmap.IncrementalPipelineOptions()
    options.random_seed = cfg.seed
    options.num_threads = thread_budget()
    return pycolmap.incremental_mapping(
        database, images, out, options, next_image_callback=lambda: progress.advance(task)
    )


def _consistent_pieces(result: SfMResult, progress: Any) -> list:
    """The importer's consistency check on the model (pairs with few shared points only)."""
    from neoedit.data.pieces import find_pieces

    task = progress.add_task(f"checking the {result.mapper} model", total=1, status="")
    pieces, _ = find_pieces(read_colmap(result.model, result.images))
    progress.advance(task)
    return pieces


def is_sequential(cfg: SfMConfig, photos: int) -> bool:
    return cfg.matcher == "sequential" or (cfg.matcher == "auto" and photos > 40)


def match_pairs(pycolmap, database: Path, photos: int, cfg: SfMConfig) -> None:  # noqa: ANN001
    """Feature matches between the photos of ``database``: sequential (neighbours in name
    order) or exhaustive, as ``cfg.matcher`` says ('auto': sequential beyond 40 photos)."""
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = thread_budget()
    if is_sequential(cfg, photos):
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = cfg.overlap
        pairing.loop_detection = False  # needs a vocabulary tree (a download)
        pycolmap.match_sequential(
            database, matching, pairing_options=pairing, device=pycolmap.Device.cpu
        )
    else:
        pycolmap.match_exhaustive(database, matching, device=pycolmap.Device.cpu)


def _largest(models: dict, folder: Path, images: Path, total: int, mapper: str) -> SfMResult | None:
    """The model with the most registered photos, written to ``folder``; None: no model."""
    if not models:
        return None
    rec = models[max(models, key=lambda k: models[k].num_reg_images())]
    folder.mkdir(parents=True, exist_ok=True)
    rec.write_binary(str(folder))
    return SfMResult(folder, images, int(rec.num_reg_images()), total, len(models), mapper)
