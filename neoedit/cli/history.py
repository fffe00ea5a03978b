"""``neo log``, ``neo restore``, ``neo diff``: the versions of a scene store."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tyro
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from neoedit.errors import NeoError
from neoedit.records import own_edit
from neoedit.utils.options import at_least_one

console = Console()


def _motion_text(record: dict[str, Any]) -> str:
    """'+x,+y,+z m, yaw' of each moved object (from its 4x4 transforms and boxes); '?' when
    the record's motion cannot be read."""
    parts = []
    try:
        for t, b in zip(record.get("transforms") or [], record.get("boxes") or [], strict=False):
            t = np.asarray(t, dtype=np.float64).reshape(4, 4)
            c = np.asarray(b["center"], dtype=np.float64).reshape(3)
            shift = t[:3, :3] @ c + t[:3, 3] - c
            yaw = math.degrees(math.atan2(t[1, 0], t[0, 0]))
            parts.append(f"[{', '.join(f'{v:+.3f}' for v in shift)}] m {yaw:+.0f}°")
    except (KeyError, TypeError, ValueError, IndexError):
        return "?"
    return "; ".join(parts)


def _number(value: Any) -> float:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else 0.0


def _row(name: str, meta: dict[str, Any], parent: str, size: int | None) -> list[str]:
    """One line of ``neo log``; a record with missing or malformed fields shows '?' there
    (the records are JSON a user can edit: the log must still list every version)."""
    rec = own_edit(meta)
    if rec is None:
        what, prompt, motion, secs = "train", "", "", _number(meta.get("train_seconds"))
    else:
        moves = [p.details for p in rec.parts()] or [rec.details]  # a batch: its edits' motions
        what, prompt = rec.label, rec.prompt or "box"
        motion = "; ".join(t for t in map(_motion_text, moves) if t)
        secs = _number(rec.seconds)
    mb = "" if not isinstance(size, (int, float)) else f"{size / 1e6:.1f} MB"
    cells = [name, str(meta.get("version_id", "?")), str(parent), what, prompt, motion]
    return [escape(c) for c in cells] + [f"{secs:.0f} s", mb]


@dataclass
class LogCommand:
    """The versions of a scene: name, id, parent, edit, prompt, motion, time, size (the
    bytes that version added to its store). The current version of a store is marked *."""

    scene: tyro.conf.Positional[Path]
    """Scene store (or a single scene folder: its lineage of edits)."""

    def run(self) -> None:
        from neoedit.storage import SceneStore, is_store

        cols = ["version", "id", "parent", "edit", "prompt", "motion", "time", "size"]
        table = Table(*cols, title=escape(str(self.scene)))
        if is_store(self.scene):
            store = SceneStore(self.scene)
            current, total = store.current, store.size_bytes()
            for name in store.names():
                info = store.info(name)
                parent = info.manifest.get("parent") or (info.meta.get("parent") or "-")
                mark = f"{name} *" if name == current else name
                table.add_row(*_row(mark, info.meta, parent, info.manifest.get("bytes")))
            console.print(table)
            console.print(f"{len(store.names())} versions, {total / 1e6:.1f} MB in all")
            if current not in store.names():
                _warn_no_current(self.scene, current)
            return
        from neoedit.scene import read_scene_meta

        meta = read_scene_meta(Path(self.scene))
        edits = list(meta.edits)  # the lineage that led to this folder
        root = edits[0].parent if edits else meta.version_id
        trained = {"version_id": root or "?", "train_seconds": meta.train_seconds}
        table.add_row(*_row("" if edits else str(self.scene), trained, "-", None))
        for k, rec in enumerate(edits):
            name = str(self.scene) if k == len(edits) - 1 else ""
            one = {"edits": [rec.to_dict()], "version_id": rec.version or "?"}
            table.add_row(*_row(name, one, rec.parent or "-", None))
        console.print(table)


def _warn_no_current(store: Path, current: str | None) -> None:
    """A store whose store.json names no version that exists: commands that read its current
    version will refuse it, so the log says so and how to mend it."""
    what = (
        "names no current version"
        if current is None
        else f"names {current!r} as current, which is not a version of the store"
    )
    Console(stderr=True).print(
        f"warning: {escape(str(store))}/store.json {escape(what)}; make one current "
        f"with: neo restore {escape(str(store))} VERSION"
    )


@dataclass
class RestoreCommand:
    """Make an earlier version of a scene store current again (undo). Nothing is deleted:
    later versions stay in the store and can be restored in turn."""

    scene: tyro.conf.Positional[Path]
    """Scene store."""
    version: tyro.conf.Positional[str]
    """Version name (e.g. step_2) or a prefix of its id."""

    def run(self) -> None:
        from neoedit.storage import SceneStore, is_store

        if not is_store(self.scene):
            raise NeoError(f"{self.scene} is not a scene store (neo plan --out makes one)")
        store = SceneStore(self.scene)
        name = store.find(self.version)
        before = store.current
        store.set_current(name)
        console.print(f"{escape(str(self.scene))}: current version {before} -> {name}")


@dataclass
class DiffCommand:
    """Render two versions of a scene store from the same cameras, side by side with their
    difference (amplified 4x); writes OUT/diff.png and prints how much each view changed."""

    scene: tyro.conf.Positional[Path]
    """Scene store."""
    a: tyro.conf.Positional[str]
    """First version (name or id prefix)."""
    b: tyro.conf.Positional[str]
    """Second version."""
    out: Path | None = None
    """Output folder (default: outputs/diff/<store>_<a>_<b>)."""
    views: int = at_least_one(3)
    """Held-out scan views to render (training views when the scan has none)."""
    overwrite: bool = False
    """Replace OUT if it holds an earlier diff."""
    device: str = "auto"

    def run(self) -> None:
        from neoedit.scene import load_scene
        from neoedit.storage import SceneStore, is_store
        from neoedit.utils.device import resolve_device
        from neoedit.utils.io import (
            atomic_directory,
            atomic_write_json,
            check_writable_output,
            write_png,
        )
        from neoedit.viz.contact_sheet import tile_images
        from neoedit.viz.versions import difference_image, pick_views, render_versions

        if not is_store(self.scene):
            raise NeoError(f"{self.scene} is not a scene store (neo plan --out makes one)")
        store = SceneStore(self.scene)
        a, b = store.find(self.a), store.find(self.b)
        out = self.out or Path("outputs/diff") / f"{Path(self.scene).name}_{a}_{b}"
        check_writable_output(out, [self.scene], "diff", self.overwrite)
        device = resolve_device(self.device)
        va, vb = load_scene(store.root / a, device), load_scene(store.root / b, device)
        rows = render_versions([va, vb], pick_views(va, self.views))
        tiles, labels, report = [], [], []
        for k, (ia, ib) in enumerate(rows):
            mse = float(np.mean((ia.astype(np.float64) - ib.astype(np.float64)) ** 2)) / 255**2
            psnr = round(10 * math.log10(1 / mse), 2) if mse > 0 else None  # None: identical
            report.append({"view": k, "psnr_a_vs_b": psnr, "identical": psnr is None})
            tiles += [ia, ib, difference_image(ia, ib)]
            labels += [a, b, f"|{a}-{b}| x4 ({'identical' if psnr is None else f'{psnr:.1f} dB'})"]
        with atomic_directory(out, overwrite=self.overwrite, kind="diff") as tmp:
            write_png(tmp / "diff.png", tile_images(tiles, cols=3, labels=labels))
            atomic_write_json(tmp / "diff.json", {"a": a, "b": b, "views": report})
        for r in report:
            console.print(
                f"view {r['view']}: {escape(a)} vs {escape(b)}: "
                + ("identical" if r["identical"] else f"PSNR {r['psnr_a_vs_b']} dB")
            )
        console.print(f"wrote {escape(str(out / 'diff.png'))}")
