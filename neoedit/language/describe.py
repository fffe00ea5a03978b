"""Words a label-free teacher can measure about a discovered object instance.

Every word comes from the data: the colour names from the training-image pixels of the
instance's surface points, the shape class and the size / height words from the points in
the frame of the support plane (x, y on the plane, z the height above it), the position
words from the instances' centres relative to one another.

Shape classes and the nouns they are described with (a query names an object by its kind;
the shape is what the geometry can tell about the kind):

* ``cylinder``: round footprint, about as wide at the top as in the middle, or taller than
  1.4 diameters whatever its top (a bottle, a can with a neck; a cone or a vase too) ->
  can, mug, cup, bottle, cylinder;
* ``sphere``: round footprint, as tall as wide, narrower at the top -> ball, sphere;
* ``box``: rectangular footprint with a flat top -> box, cube (equal sides), block, brick;
* ``flat``: much wider than tall -> plate, bowl, dish;
* ``irregular``: anything else -> toy, thing (and the colour alone: the best cue left).
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, field

import cv2
import numpy as np

from neoedit.geometry.box import OrientedBox

SHAPE_NOUNS: dict[str, tuple[str, ...]] = {
    "cylinder": ("can", "mug", "cup", "bottle", "cylinder"),
    "sphere": ("ball", "sphere"),
    "box": ("box", "block", "brick"),
    "cube": ("cube", "box", "block"),
    "flat": ("plate", "bowl", "dish"),
    "irregular": ("toy", "thing"),
}


@dataclass
class Shape:
    """Measured shape of an instance, in the support plane's frame."""

    kind: str
    """One of SHAPE_NOUNS' keys."""
    length_m: float
    """Long side of the footprint (minimum-area rectangle, 2 % trimmed)."""
    width_m: float
    """Short side of the footprint."""
    height_m: float
    """Height of the top above the support plane."""
    center: np.ndarray = field(repr=False)
    """(3,) centre of the footprint rectangle at half height, plane frame."""


def measure_shape(local: np.ndarray) -> Shape:
    """Shape class of the points (N,3) of one instance in the plane frame (z = height)."""
    height = float(np.quantile(local[:, 2], 0.98))
    rect = OrientedBox.fit_to_points(local)
    rect = OrientedBox.fit_with_yaw(local, rect.yaw_deg, trim=0.02)
    length, width = float(max(rect.size_m[:2])), float(min(rect.size_m[:2]))
    center = np.array([rect.center_m[0], rect.center_m[1], height / 2])
    kind = _shape_kind(local, length, width, height)
    return Shape(kind, length, width, height, center)


def _hull_area(xy: np.ndarray) -> float:
    from scipy.spatial import ConvexHull, QhullError  # lazy

    if len(xy) < 3:
        return 0.0
    try:
        return float(ConvexHull(xy).volume)
    except QhullError:
        return 0.0


def _circle_residual(outline: np.ndarray) -> float:
    """Median relative radial error of outline points (K,2) to their least-squares circle
    (Kasa fit), refitted once without the points far off it (a mug's handle)."""
    keep = np.ones(len(outline), bool)
    err = np.ones(len(outline))
    for _ in range(2):
        x, y = outline[keep, 0], outline[keep, 1]
        a = np.c_[2 * x, 2 * y, np.ones(len(x))]
        (cx, cy, c), *_ = np.linalg.lstsq(a, x**2 + y**2, rcond=None)
        radius = np.sqrt(max(c + cx**2 + cy**2, 1e-12))
        err = np.abs(np.linalg.norm(outline - [cx, cy], axis=1) / radius - 1)
        keep = err <= max(2.5 * float(np.median(err)), 0.02)
    return float(np.median(err[keep]))


def outline_fit(xy: np.ndarray, bins: int = 36) -> tuple[float, float]:
    """How well the footprint's outline fits a circle and a rectangle: (circle residual,
    rectangle residual), median relative errors of the outline (per angular bin about the
    centre of the footprint's minimum-area rectangle, the 95th percentile radius of its
    points) against each model; the rectangle has the yaw and the 1-99 % extents of the
    points."""
    (cx, cy), _, angle = cv2.minAreaRect(xy.astype(np.float32))
    yaw = np.radians(angle)
    axes = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])
    uv = (xy - [cx, cy]) @ axes.T
    lo, hi = np.quantile(uv, 0.01, axis=0), np.quantile(uv, 0.99, axis=0)
    uv = uv - (lo + hi) / 2  # centre of the trimmed extents
    half = (hi - lo) / 2
    radius = np.linalg.norm(uv, axis=1)
    theta = np.arctan2(uv[:, 1], uv[:, 0])
    which = np.minimum(((theta + np.pi) / (2 * np.pi) * bins).astype(int), bins - 1)
    outline, model = [], []
    for b in range(bins):
        r = radius[which == b]
        if len(r) < 3:
            continue
        t = -np.pi + (b + 0.5) * 2 * np.pi / bins
        rq = float(np.quantile(r, 0.95))
        outline.append((rq * np.cos(t), rq * np.sin(t)))
        model.append(min(half[0] / max(abs(np.cos(t)), 1e-9), half[1] / max(abs(np.sin(t)), 1e-9)))
    if len(outline) < bins // 2:
        return 1.0, 1.0
    pts = np.array(outline)
    rect = float(np.median(np.abs(np.linalg.norm(pts, axis=1) / np.array(model) - 1)))
    return _circle_residual(pts), rect


def top_cover(local: np.ndarray, height: float) -> float:
    """Hull area of the points in the top 15 % of the height over the whole footprint's:
    about 1 for a flat top or an open rim, well below for a dome."""
    full = _hull_area(local[:, :2])
    return _hull_area(local[local[:, 2] >= 0.85 * height, :2]) / full if full > 0 else 1.0


def _shape_kind(local: np.ndarray, length: float, width: float, height: float) -> str:
    if height < 0.35 * length:
        return "flat"
    disc, rect = outline_fit(local[:, :2])
    top = top_cover(local, height)
    if rect < disc and rect <= 0.08 and top >= 0.6:
        equal = width >= 0.8 * length and 0.75 * length <= height <= 1.33 * length
        return "cube" if equal else "box"
    if disc <= rect and disc <= 0.06 and width >= 0.55 * length:
        if top < 0.65 and 0.7 * length <= height <= 1.4 * length:
            return "sphere"
        if top >= 0.65 or height > 1.4 * length:
            # a tall round object whose top narrows is a bottle or a can with a neck
            # (beer_can: top cover 0.64, height 2.5x its diameter), not a sphere
            return "cylinder"
    return "irregular"


_PLACES = {
    "left": "on the left",
    "right": "on the right",
    "middle": "in the middle",
    "front": "at the front",
    "back": "at the back",
}
POSITION_WORDS = tuple(_PLACES)

# hue boundaries (degrees) of the chromatic colour names, checked in order
_HUES = ((15, "red"), (40, "orange"), (70, "yellow"), (165, "green"), (255, "blue"))


def colour_name(rgb: np.ndarray) -> str:
    """Name of one RGB colour (3,) in 0..255: black / white / grey or a hue name; orange and
    red that are dark are brown, light desaturated red is pink."""
    h, s, v = colorsys.rgb_to_hsv(*(float(c) / 255.0 for c in rgb))
    deg = h * 360.0
    if v < 0.2:
        return "black"
    if s < 0.2:
        return "white" if v > 0.75 else "grey"
    if 15 <= deg < 45 and v < 0.6:
        return "brown"
    if (deg < 15 or deg >= 330) and s < 0.7 and v > 0.6:
        return "pink"
    for bound, name in _HUES:
        if deg < bound:
            return name
    if deg < 290:
        return "purple"
    return "pink" if deg < 330 else "red"


def colour_words(rgb: np.ndarray, second_share: float = 0.25) -> list[str]:
    """The dominant colour name(s) of pixels (N,3): the most frequent name, and a second one
    when it covers at least ``second_share`` of the pixels ("black and white")."""
    if len(rgb) == 0:
        return []
    # quantise to 4-bit levels so that naming stays cheap for many pixels
    q, counts = np.unique((np.asarray(rgb) // 16).astype(np.int64), axis=0, return_counts=True)
    tally: dict[str, int] = {}
    for colour, n in zip(q * 16 + 8, counts, strict=True):
        name = colour_name(colour)
        tally[name] = tally.get(name, 0) + int(n)
    ranked = sorted(tally.items(), key=lambda kv: -kv[1])
    words = [ranked[0][0]]
    if len(ranked) > 1 and ranked[1][1] >= second_share * len(rgb):
        words.append(ranked[1][0])
    return words


def relative_words(
    shapes: list[Shape], right: np.ndarray, forward: np.ndarray, spread_m: float = 0.05
) -> list[list[str]]:
    """Per instance: size (small / large), height (tall / short) and position (left / right /
    middle, front / back) words relative to the other instances. ``right`` and ``forward``
    are unit plane-frame (2,) directions of the viewer."""
    words: list[list[str]] = [[] for _ in shapes]
    if len(shapes) < 2:
        return words
    volumes = np.array([s.length_m * s.width_m * s.height_m for s in shapes])
    heights = np.array([s.height_m for s in shapes])
    centres = np.array([s.center[:2] for s in shapes])
    order = np.argsort(-heights)
    for i in range(len(shapes)):
        if volumes[i] >= 2.0 * np.max(np.delete(volumes, i)):
            words[i].append("large")
        elif volumes[i] <= 0.5 * volumes.max():
            words[i].append("small")
        if i == order[0] and heights[i] >= 1.2 * heights[order[1]]:
            words[i].append("tall")
        elif heights[i] <= 0.6 * heights.max():
            words[i].append("short")
    for axis, (low, high) in ((right, ("left", "right")), (forward, ("front", "back"))):
        coord = centres @ axis
        span = float(coord.max() - coord.min())
        if span < spread_m:
            continue
        rel = (coord - (coord.max() + coord.min()) / 2) / (span / 2)
        for i, r in enumerate(rel):
            if r <= -0.5:
                words[i].append(low)
            elif r >= 0.5:
                words[i].append(high)
            elif len(shapes) >= 3 and axis is right:
                words[i].append("middle")
    return words


def phrases(colours: list[str], kind: str, relative: list[str]) -> tuple[str, list[str]]:
    """(description, phrases embedded for it) of one instance.

    The phrases are the colour with each noun of the shape ("red can", "red mug", ...) and,
    for a confident shape class, its first three nouns alone (the first twice), so a
    one-word query ("can", "mug", "ball") lands close too; for an irregular shape, the
    colour alone. Measured with MiniLM on NEO-Sim (benchmarks/bench_language_free.py):
    phrases with the size / position words ("red can on the left") made name queries no
    better and single nouns worse, and sentence embeddings barely tell "left" from "right";
    those words stay in the description only."""
    nouns = SHAPE_NOUNS[kind]
    colour = " and ".join(colours)
    out = [f"{colour} {noun}".strip() for noun in nouns]
    if kind != "irregular":
        out += [nouns[0], *nouns[:3]]  # the class's own name counts twice
    elif colour:
        out.append(colour)
    position = [w for w in relative if w in POSITION_WORDS]
    sizes = [w for w in relative if w not in POSITION_WORDS]
    noun, kinds = (
        ("object", "irregular shape") if kind == "irregular" else (nouns[0], "/".join(nouns))
    )
    head = " ".join([*sizes, colour, noun]).strip()
    where = "".join(" " + _PLACES[w] for w in position)
    return f"{head} ({kinds}){where}", out
