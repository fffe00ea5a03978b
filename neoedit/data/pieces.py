"""Is a reconstruction one consistent piece? Checks consecutive photos of a capture.

A walk around an object gives photos whose neighbours in name order overlap. When
structure-from-motion breaks such a walk into pieces and folds them onto each other (a
repeating print or floor tiles can do that), consecutive photos across a break share
(almost) no sparse points, yet their images still match each other well -- only not under
the model's poses. A consecutive pair is examined when

1. it shares few sparse points (fewer than ``min_shared`` and a small fraction of the median;
   with no sparse points (LLFF, a dataset's transforms.json) every pair is examined);

and its SIFT matches are compared with two geometries: the photos' own (a fundamental matrix
fitted to the matches) and the model's (the epipolar lines its poses predict). A pair is

- a **break** (strong evidence: the import refuses) when the photos' own geometry explains
  many matches (``min_matches``, and ``min_inlier_share`` of the candidates), they lie
  farther than ``max_epipolar_px`` from the model's epipolar lines (median), and the model
  explains at most ``max_agree_share`` as many of the candidates;
- **doubtful** (a warning with the evidence, the import goes on) when the median is above
  ``max_epipolar_px`` but the evidence is weaker: too few matches for a clear geometry of
  their own, or a model that still explains a good share of them (a repeating texture
  whose best geometry is shifted by a period; mildly noisy poses);
- consistent otherwise. Pairs that do not overlap (an unordered collection) are never breaks.

Measured (``benchmarks/bench_pieces.py``): across beer_can's three folds the photos explain
26-40 matches 46-79 px from the model's lines and the model 0-3; NEO-Sim's checker table
gives a wrong geometry of 18-24 matches (shifted by a square) 11-16 px from the lines of
poses that are right, which explain 8-16.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from neoedit.data.capture import Capture, read_photo
from neoedit.data.scene_data import SceneData
from neoedit.errors import DataError

Verdict = Literal["consistent", "break", "doubtful", "no overlap"]


@dataclass
class PieceCheckConfig:
    min_shared: int = 10
    """Consecutive photos sharing fewer sparse points than this (and than
    ``shared_fraction`` of the median) are examined with feature matches."""
    shared_fraction: float = 0.1
    match_width_px: int = 800
    """Photos are matched at this width (SIFT)."""
    min_matches: int = 15
    """Fewer fundamental-matrix inliers than this: the photos do not overlap (no break)."""
    min_inlier_share: float = 0.3
    """A break also needs the fundamental matrix to explain at least this share of the
    candidate (ratio-test) matches: a consensus of a few chance matches among many (a
    textureless backdrop) is no evidence against the poses."""
    max_epipolar_px: float = 10.0
    """Median distance of the matches to the epipolar lines of the model's poses, in pixels
    of the photos as matched (shrunk to ``match_width_px`` if wider), above which the poses
    may contradict the photos. Consistent pairs
    measure under 1 px with a lens model, up to ~5 px when the lens distortion is unknown
    (LLFF); pairs across a folded break measure tens of pixels."""
    agree_px: float = 3.0
    """A match agrees with the model's poses within this many pixels of its epipolar line."""
    max_agree_share: float = 0.25
    """A break needs the model's poses to explain at most this share of what the photos' own
    geometry explains (counted over every candidate match: on a repeating texture the
    photos' best geometry can be a wrong one, shifted by a period, while the model still
    explains as many matches)."""

    def check(self) -> None:
        """DataError naming the first option out of range."""
        for name in ("min_inlier_share", "max_agree_share", "shared_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                flag = name.replace("_", "-")
                raise DataError(f"--check.{flag} must be in [0, 1], got {getattr(self, name)}")
        for name in ("max_epipolar_px", "agree_px"):
            if not getattr(self, name) > 0:
                flag = name.replace("_", "-")
                raise DataError(f"--check.{flag} must be positive, got {getattr(self, name)}")
        if self.min_matches < 8 or self.match_width_px < 64:
            raise DataError(
                "--check.min-matches must be >= 8 (a fundamental matrix needs 8) and "
                f"--check.match-width-px >= 64, got {self.min_matches} and {self.match_width_px}"
            )


@dataclass
class PairCheck:
    first: int
    """The pair is photo ``first`` and photo ``first + 1``."""
    shared_points: int
    matches: int
    """Matches the photos' own fundamental matrix explains (with too few candidates for
    one: the candidates)."""
    epipolar_px: float | None
    """Median epipolar distance of those matches under the model's poses, in pixels of the
    photos as matched (at most ``match_width_px`` wide); None: too few matches, or the two
    cameras at one place (no epipolar geometry to test)."""
    candidates: int = 0
    """Ratio-test matches between the two photos."""
    agree: int = 0
    """Of the candidates, those within ``agree_px`` of the model's epipolar lines: the
    matches the model's poses explain (the photos' own geometry explains ``matches``)."""

    def verdict(self, cfg: PieceCheckConfig) -> Verdict:
        if self.epipolar_px is None:
            return "no overlap"
        if self.epipolar_px <= cfg.max_epipolar_px:
            return "consistent"
        clear = self.matches >= max(cfg.min_matches, cfg.min_inlier_share * self.candidates)
        contradicted = self.agree <= cfg.max_agree_share * self.matches
        return "break" if clear and contradicted else "doubtful"

    def is_break(self, cfg: PieceCheckConfig) -> bool:
        return self.verdict(cfg) == "break"

    def describe(self, names: list[str]) -> str:
        """'first -> second: evidence', the photos named by ``names`` (in check order)."""
        return f"{names[self.first]} -> {names[self.first + 1]}: {self.evidence()}"

    def evidence(self) -> str:
        """One line for a person: what the matches say about the model's poses."""
        if self.epipolar_px is None:
            return f"{self.matches} matches: too few to tell, or no baseline"
        return (
            f"of {self.candidates} matches, the photos' own geometry explains {self.matches} "
            f"(they lie {self.epipolar_px:.1f} px from the model's epipolar lines, median), the "
            f"model's poses {self.agree}"
        )


@dataclass
class _Views:
    """What the check reads of a capture or a dataset, photo by photo."""

    count: int
    grey: Callable[[int], np.ndarray]
    """Photo i as a full-size greyscale uint8 image."""
    lens: Callable[[int], tuple[np.ndarray, np.ndarray]]
    """(K with OpenCV's pixel-centre convention, OpenCV distortion coefficients)."""
    camera_to_world: np.ndarray
    """(N,4,4), OpenGL axes."""
    valid: Callable[[int], np.ndarray | None] = lambda i: None  # noqa: E731
    """Photo i's pixels worth matching (bool, full size; None: all): an undistorted
    image's smeared border is not."""
    _features: dict[int, tuple] = field(default_factory=dict)
    """Features of the last photo matched (each photo is the second of one pair and the
    first of the next)."""


def _capture_views(capture: Capture) -> _Views:
    def lens(i: int) -> tuple[np.ndarray, np.ndarray]:
        k = capture.lenses[i].matrix()
        k[:2, 2] -= 0.5  # COLMAP's principal point -> OpenCV's pixel-centre convention
        return k, capture.lenses[i].distortion()

    return _Views(
        len(capture),
        lambda i: read_photo(capture.image_dir / capture.names[i], grey=True),
        lens,
        capture.camera_to_world,
    )


def _data_views(data: SceneData) -> _Views:
    """A loaded dataset: its (undistorted) images and pinhole cameras."""
    import cv2

    c = data.cameras

    def lens(i: int) -> tuple[np.ndarray, np.ndarray]:
        k = np.array([[c.fx[i], 0.0, c.cx[i] - 0.5], [0.0, c.fy[i], c.cy[i] - 0.5], [0, 0, 1]])
        return k, np.zeros(4)

    mask = data.loss_mask
    return _Views(
        len(data),
        lambda i: cv2.cvtColor(data.images[i], cv2.COLOR_RGB2GRAY),
        lens,
        c.camera_to_world,
        lambda i: None if mask is None else mask[i],
    )


def _features(views: _Views, i: int, width: int) -> tuple:
    """SIFT keypoints and descriptors of photo i, matched at most ``width`` wide, and that
    scale; kept for the next pair."""
    import cv2

    if i not in views._features:
        image, valid = views.grey(i), views.valid(i)
        scale = min(1.0, width / image.shape[1])
        if scale < 1.0:
            image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        mask = None
        if valid is not None:
            size = (int(image.shape[1]), int(image.shape[0]))
            mask = cv2.resize(valid.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST)
        sift = cv2.SIFT_create(nfeatures=3000)  # type: ignore[attr-defined]
        views._features.clear()
        views._features[i] = (*sift.detectAndCompute(image, mask), scale)
    return views._features[i]


def _normalised(views: _Views, i: int, uv: np.ndarray) -> np.ndarray:
    """Pixel coordinates (full resolution) -> normalised camera coordinates (x/z, y/z)."""
    import cv2

    k, dist = views.lens(i)
    pts = cv2.undistortPoints(uv.reshape(-1, 1, 2), k, dist)
    return pts.reshape(-1, 2)


def _relative_essential(c2w: np.ndarray, i: int, j: int) -> np.ndarray:
    """E with x_j^T E x_i = 0 for normalised OpenCV camera coordinates of photos i, j."""
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    w2c_i = np.linalg.inv(c2w[i] @ flip)
    w2c_j = np.linalg.inv(c2w[j] @ flip)
    rel = w2c_j @ np.linalg.inv(w2c_i)
    r, t = rel[:3, :3], rel[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return tx @ r


def _matches(views: _Views, i: int, cfg: PieceCheckConfig):  # noqa: ANN202 (arrays, scales)
    """SIFT ratio-test matches of photos i and i+1: full-resolution pixel coordinates
    (OpenCV convention) in each, and the two photos' matching scales."""
    import cv2

    kp_i, des_i, s_i = _features(views, i, cfg.match_width_px)
    kp_j, des_j, s_j = _features(views, i + 1, cfg.match_width_px)  # kept for the next pair
    if des_i is None or des_j is None or len(kp_i) < 8 or len(kp_j) < 8:
        return np.zeros((0, 2)), np.zeros((0, 2)), s_i, s_j
    pairs = cv2.BFMatcher().knnMatch(des_i, des_j, k=2)
    good = [m[0] for m in pairs if len(m) == 2 and m[0].distance < 0.75 * m[1].distance]
    # OpenCV keypoints (pixel centres on integers) at the matching scale -> full resolution
    uv_i = (np.array([kp_i[m.queryIdx].pt for m in good], np.float64).reshape(-1, 2) + 0.5) / s_i
    uv_j = (np.array([kp_j[m.trainIdx].pt for m in good], np.float64).reshape(-1, 2) + 0.5) / s_j
    return uv_i - 0.5, uv_j - 0.5, s_i, s_j


def _check_pair(views: _Views, i: int, shared: int, cfg: PieceCheckConfig) -> PairCheck:
    """Match photos i and i+1 and measure their epipolar distance under the model."""
    import cv2

    j = i + 1
    uv_i, uv_j, s_i, s_j = _matches(views, i, cfg)
    n = len(uv_i)
    if n < cfg.min_matches:
        return PairCheck(i, shared, n, None, n)
    _, inlier = cv2.findFundamentalMat(uv_i, uv_j, cv2.FM_RANSAC, 1.0 / s_i, 0.999)
    if inlier is None or int(inlier.sum()) < cfg.min_matches:
        return PairCheck(i, shared, 0 if inlier is None else int(inlier.sum()), None, n)
    keep = inlier.ravel().astype(bool)
    essential = _relative_essential(views.camera_to_world, i, j)
    if np.abs(essential).max() < 1e-9:  # one camera place: no epipolar line to test
        return PairCheck(i, shared, int(keep.sum()), None, n)
    h_i = np.c_[_normalised(views, i, uv_i), np.ones(n)]
    h_j = np.c_[_normalised(views, j, uv_j), np.ones(n)]
    lines = h_i @ essential.T  # lines in photo j
    dist = np.abs((h_j * lines).sum(1)) / np.linalg.norm(lines[:, :2], axis=1).clip(1e-12)
    dist_px = dist * views.lens(j)[0][0, 0] * s_j
    agree = int((dist_px <= cfg.agree_px).sum())  # of every candidate: the model's support
    return PairCheck(i, shared, int(keep.sum()), float(np.median(dist_px[keep])), n, agree)


def _pieces(
    views: _Views, suspects: list[int], shared: np.ndarray, cfg: PieceCheckConfig,
    progress: Callable[[list[int]], Iterable[int]] | None = None,
) -> tuple[list[np.ndarray], list[PairCheck]]:  # fmt: skip
    pairs = suspects if progress is None else progress(suspects)
    checks = [_check_pair(views, i, int(shared[i]), cfg) for i in pairs]
    cuts = [c.first + 1 for c in checks if c.is_break(cfg)]
    return np.split(np.arange(views.count), cuts), checks


def find_pieces(
    capture: Capture, cfg: PieceCheckConfig | None = None
) -> tuple[list[np.ndarray], list[PairCheck]]:
    """Index arrays of the consistent pieces (in name order) and the pairs examined."""
    cfg = cfg or PieceCheckConfig()
    n = len(capture)
    if n < 2:
        return [np.arange(n)], []
    if capture.point_tracks:
        shared = capture.shared_with_next()
        limit = min(cfg.min_shared, cfg.shared_fraction * float(np.median(shared)))
        suspects = [i for i in range(n - 1) if shared[i] < max(limit, 1)]
    else:
        shared = np.zeros(n - 1, np.int64)
        suspects = list(range(n - 1))
    return _pieces(_capture_views(capture), suspects, shared, cfg)


def find_pieces_in_data(
    data: SceneData,
    cfg: PieceCheckConfig | None = None,
    progress: Callable[[list[int]], Iterable[int]] | None = None,
) -> tuple[list[np.ndarray], list[PairCheck]]:
    """:func:`find_pieces` for a loaded dataset (frames in its order, every consecutive pair
    examined: a transforms.json has no sparse points); ``progress`` wraps the pair list."""
    cfg = cfg or PieceCheckConfig()
    pairs = list(range(len(data) - 1))
    return _pieces(_data_views(data), pairs, np.zeros(len(pairs), np.int64), cfg, progress)
