"""``neo info``: what a dataset holds, as our parsers read it."""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import tyro
from rich.console import Console
from rich.markup import escape

from neoedit.data import load_scene_data
from neoedit.data.downscale import DataConfig
from neoedit.data.pieces import PieceCheckConfig, find_pieces_in_data
from neoedit.data.scene_data import SceneData
from neoedit.data.sparse_depth import is_sparse
from neoedit.errors import DataError, MissingFramesWarning, NeoWarning
from neoedit.training.defaults import BOX_SOURCES, scene_box_and_source
from neoedit.utils.progress import track


@dataclass
class InfoCommand:
    """Load a dataset (nerfstudio transforms.json or Blender) and print what it holds: the
    frames and their size (and any downscale), the lenses, missing images, depth, labels,
    the scene box and where it comes from, whether the poses agree with the photos, and the
    command that trains it."""

    data: tyro.conf.Positional[Path]
    """Dataset folder (or its transforms.json)."""
    data_cfg: Annotated[DataConfig, tyro.conf.OmitArgPrefixes] = dataclasses.field(
        default_factory=DataConfig
    )
    check_poses: bool = True
    """Match consecutive frames (SIFT) and measure them against the poses, as ``neo import``
    does (about 0.1 s a pair at 800 px): a model broken into pieces trains blurry."""

    def run(self) -> None:
        c = Console()
        try:
            with warnings.catch_warnings(record=True) as caught:  # missing frames: listed
                warnings.simplefilter("always", NeoWarning)
                d = load_scene_data(
                    self.data, dataclasses.replace(self.data_cfg, skip_missing=True)
                )
        except DataError:  # another fault too: say it as neo train would (missing images first)
            load_scene_data(self.data, self.data_cfg)
            raise
        missing = [str(w.message) for w in caught if issubclass(w.category, MissingFramesWarning)]
        for w in caught:
            if not issubclass(w.category, MissingFramesWarning):
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        c.print(f"[bold]{escape(str(d.root))}[/]: {len(d)} frames of {d.width}x{d.height}")
        if d.downscaled > 1:
            how = f"read from images_{d.downscaled}/" if d.pre_shrunk else "shrunk on load"
            c.print(f"downscaled {d.downscaled}x ({how})")
        if missing:
            what = missing[0].removesuffix("; those frames are skipped")
            c.print(f"[yellow]missing:[/] {escape(what)}; training needs --skip-missing")
        c.print(f"lenses: {escape(d.lens_note)}")
        _print_contents(c, d)
        if self.check_poses and len(d) > 1:
            _print_pose_check(c, d)
        options = dataclasses.asdict(self.data_cfg) | {"skip_missing": bool(missing)}
        flags = "".join(
            f" --{k.replace('_', '-')}" + ("" if isinstance(v, bool) else f" {v}")
            for k, v in options.items()
            if (v if isinstance(v, bool) else v not in (None, 1))
        )
        c.print(f"train it: neo train {escape(str(self.data))}{flags} --out <scene folder>")


def _print_contents(c: Console, d: SceneData) -> None:
    """Splits, cameras, depth, labels, alpha and the scene box."""
    c.print("splits: " + ", ".join(f"{k}={len(v)}" for k, v in d.split.items()))
    c.print(
        f"focal (px): {np.median(d.cameras.fx):.1f}; camera centres within "
        f"{np.round(d.camera_aabb_m(), 3).tolist()} m"
    )
    depth = "no"
    if d.depth_m is not None:
        share = float((d.depth_m > 0).mean())
        depth = f"sparse ({share:.2%} of the pixels)" if is_sparse(d.depth_m) else "yes"
    c.print(
        f"depth: {depth}; instance labels: "
        f"{'yes' if d.instance_ids is not None else 'no'}; loss masks: {'yes' if d.loss_mask is not None else 'no'}"
    )
    if d.instance_names:
        c.print("instances: " + ", ".join(f"{i}={n}" for i, n in sorted(d.instance_names.items())))
    for obj in d.objects:
        c.print(f"  {escape(str(obj['name']))}: box {obj['box']}")
    transparent = d.alpha is not None and bool((d.alpha < 255).any())
    c.print(f"alpha: {'yes (transparent background)' if transparent else 'no'}")
    box, source = scene_box_and_source(d)
    c.print(f"scene box: {np.round(box, 3).tolist()} from {BOX_SOURCES[source]}")


def _print_pose_check(c: Console, d: SceneData) -> None:
    """Whether consecutive frames match under the poses, with the evidence."""
    cfg = PieceCheckConfig()
    pieces, checks = find_pieces_in_data(
        d, cfg, lambda pairs: track(pairs, "matching consecutive frames")
    )
    verdicts = [ch.verdict(cfg) for ch in checks]
    seen = [ch for ch, v in zip(checks, verdicts, strict=True) if v != "no overlap"]
    if not seen:
        c.print(
            f"poses: not checked: none of the {len(checks)} consecutive pairs overlap enough "
            "to match (an unordered collection?)"
        )
        return
    fits = [
        ch.epipolar_px or 0.0 for ch, v in zip(checks, verdicts, strict=True) if v == "consistent"
    ]
    if len(pieces) == 1:
        tail = f"; worst median epipolar distance {max(fits):.2f} px" if fits else ""
        doubts = verdicts.count("doubtful")
        weak = f"; {doubts} disagree, too weakly to call it broken:" if doubts else ""
        c.print(
            f"poses: consistent ({len(seen)} of {len(checks)} consecutive pairs matched{tail}){weak}"
        )
    else:
        c.print(
            f"[bold red]poses: broken into {len(pieces)} inconsistent pieces[/] (a field "
            "trained on every frame would be blurry):"
        )
    for ch, v in zip(checks, verdicts, strict=True):
        if v in ("break", "doubtful"):
            c.print(f"  {v}: {escape(ch.describe(d.file_paths))}")
