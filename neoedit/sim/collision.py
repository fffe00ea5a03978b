"""Concave collision shapes for PyBullet objects.

PyBullet collides each object of a moving body's mesh as its convex hull, and
pybullet_data's mug collides with a closed cylinder: its inside is solid, so a finger
that would go over the rim meets a lid that is not there. For an object marked
``concave`` in its spec, the visual mesh is split into convex parts with PyBullet's own
V-HACD, once per mesh (cached by content), and the object is loaded from a copy of its
URDF that collides with the parts (PyBullet loads a multi-part ``.obj`` as a compound).
"""

from __future__ import annotations

import contextlib
import copy
import ctypes
import hashlib
import os
import sys
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from neoedit.errors import NeoError, SpecError
from neoedit.sim._pybullet import pb
from neoedit.utils.cache import cache_dir as user_cache_dir
from neoedit.utils.io import atomic_write_bytes

VHACD = {"resolution": 200_000, "concavity": 0.0025, "maxNumVerticesPerCH": 64}
"""V-HACD settings (a mug: 16 parts, its inside open down to the bottom)."""
FORMAT = 2
"""Version of what the cache holds (2: parts fitted to the mesh's bounds)."""


def cache_dir() -> Path:
    """Where derived assets live (:func:`neoedit.utils.cache.cache_dir`)."""
    root = user_cache_dir()
    if root is None:
        raise NeoError("no cache folder: set NEOEDIT_CACHE to a writable folder")
    return root


def concave_urdf(urdf: Path) -> Path:
    """A copy of ``urdf`` whose links collide with the V-HACD convex parts of their visual
    mesh (the shape the scans show; a model's collision mesh is often a closed stand-in),
    every mesh path made absolute. Cached: the same URDF and meshes give the same file."""
    try:
        tree = ET.parse(urdf)
    except (OSError, ET.ParseError) as e:
        raise SpecError(f"{urdf}: cannot read the URDF ({e})") from None
    for mesh in tree.getroot().iter("mesh"):
        mesh.set("filename", str((urdf.parent / mesh.get("filename", "")).resolve()))
    changed = 0
    for link in tree.getroot().iter("link"):
        visual, collision = link.find("visual"), link.find("collision")
        shown = None if visual is None else visual.find("geometry/mesh")
        if visual is None or collision is None or shown is None:
            continue
        origin = visual.find("origin")
        for extra in link.findall("collision")[1:]:  # one collision: the parts
            link.remove(extra)
        for old in list(collision):
            collision.remove(old)
        if origin is not None:
            collision.append(copy.deepcopy(origin))
        attrib = dict(shown.attrib)
        attrib["filename"] = str(convex_parts(Path(attrib.get("filename", ""))))
        ET.SubElement(ET.SubElement(collision, "geometry"), "mesh", attrib)
        changed += 1
    if not changed:
        raise SpecError(f"{urdf}: 'concave' needs a link with a visual mesh and a collision")
    text = ET.tostring(tree.getroot(), encoding="utf-8")
    out = cache_dir() / "urdf" / f"{urdf.stem}-{hashlib.sha256(text).hexdigest()[:16]}.urdf"
    if not out.is_file():
        atomic_write_bytes(out, text)
    return out


def convex_parts(mesh: Path) -> Path:
    """The ``.obj`` of ``mesh``'s V-HACD decomposition (computed once, then cached)."""
    if not mesh.is_file():
        raise SpecError(f"mesh not found: {mesh}")
    settings = repr((FORMAT, sorted(VHACD.items()))).encode()
    key = hashlib.sha256(mesh.read_bytes() + settings).hexdigest()
    out = cache_dir() / "vhacd" / f"{mesh.stem}-{key[:16]}.obj"
    if out.is_file():
        return out
    vertices = obj_parts(mesh)
    if not vertices:
        raise SpecError(f"{mesh}: no vertices to decompose")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise SpecError(
            f"cannot write the collision cache {out.parent} ({e}); set NEOEDIT_CACHE"
        ) from None
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:
        part = Path(tmp) / "parts.obj"
        with _quiet_stdout():  # V-HACD prints its progress from C
            pb.vhacd(str(mesh), str(part), str(Path(tmp) / "log.txt"), **VHACD)
        if not part.is_file() or part.stat().st_size == 0:
            raise SpecError(f"V-HACD could not decompose {mesh}")
        fitted = Path(tmp) / "fitted.obj"
        fitted.write_text(_fit_bounds(part.read_text(), np.concatenate(vertices)))
        os.replace(fitted, out)  # atomic: a concurrent process writes the same bytes
    return out


def _fit_bounds(obj_text: str, vertices: np.ndarray) -> str:
    """The ``.obj`` text with its vertices scaled, per axis about the bounds' centre, so its
    bounds are those of ``vertices``: V-HACD's hulls stand about half a voxel proud of the
    surface, which would lift the object off its support (the mug: 0.5 mm)."""
    ours = np.concatenate(obj_parts_text(obj_text))
    lo, hi, want_lo, want_hi = ours.min(0), ours.max(0), vertices.min(0), vertices.max(0)
    scale = (want_hi - want_lo) / np.maximum(hi - lo, 1e-12)
    lines = []
    for line in obj_text.splitlines():
        if line.startswith("v "):
            v = (np.asarray(line.split()[1:4], dtype=np.float64) - lo) * scale + want_lo
            line = "v " + " ".join(f"{x:.7f}" for x in v)
        lines.append(line)
    return "\n".join(lines) + "\n"


def obj_parts(path: str | Path) -> list[np.ndarray]:
    """Vertices (N,3) of each object (``o`` block) of an ``.obj`` file: the convex parts of
    a decomposition, or the whole mesh as one part."""
    return obj_parts_text(Path(path).read_text(errors="ignore"))


def obj_parts_text(text: str) -> list[np.ndarray]:
    """:func:`obj_parts` of an ``.obj`` file's text."""
    parts: list[list[list[str]]] = [[]]
    for line in text.splitlines():
        if line.startswith("o ") and parts[-1]:
            parts.append([])
        elif line.startswith("v "):
            parts[-1].append(line.split()[1:4])
    return [np.asarray(p, dtype=np.float64) for p in parts if p]


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Silence the process's stdout (C code's too) inside the block."""
    sys.stdout.flush()
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # captured by a test runner
        yield
        return
    saved = os.dup(fd)
    with open(os.devnull, "wb") as null:
        os.dup2(null.fileno(), fd)
        try:
            yield
        finally:
            with contextlib.suppress(OSError, AttributeError):
                ctypes.CDLL(None).fflush(None)  # C stdio's buffer, before stdout returns
            os.dup2(saved, fd)
            os.close(saved)
