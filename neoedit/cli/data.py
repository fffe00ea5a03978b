"""``neo info``: what a dataset holds, as our parsers read it."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import tyro
from rich.console import Console
from rich.markup import escape

from neoedit.data import load_scene_data
from neoedit.data.downscale import DataConfig
from neoedit.data.sparse_depth import is_sparse
from neoedit.training.defaults import BOX_SOURCES, scene_box_and_source


@dataclass
class InfoCommand:
    """Load a dataset (nerfstudio transforms.json or Blender) and print a summary."""

    data: tyro.conf.Positional[Path]
    """Dataset folder (or its transforms.json)."""
    data_cfg: Annotated[DataConfig, tyro.conf.OmitArgPrefixes] = dataclasses.field(
        default_factory=DataConfig
    )

    def run(self) -> None:
        d = load_scene_data(self.data, self.data_cfg)
        c = Console()
        c.print(f"[bold]{escape(str(d.root))}[/]: {len(d)} frames of {d.width}x{d.height}")
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
            c.print(
                "instances: " + ", ".join(f"{i}={n}" for i, n in sorted(d.instance_names.items()))
            )
        for obj in d.objects:
            c.print(f"  {escape(str(obj['name']))}: box {obj['box']}")
        transparent = d.alpha is not None and bool((d.alpha < 255).any())
        c.print(f"alpha: {'yes (transparent background)' if transparent else 'no'}")
        box, source = scene_box_and_source(d)
        c.print(f"scene box: {np.round(box, 3).tolist()} from {BOX_SOURCES[source]}")
        flags = "".join(
            f" --{k.replace('_', '-')} {v}"
            if not isinstance(v, bool)
            else f" --{k.replace('_', '-')}"
            for k, v in dataclasses.asdict(self.data_cfg).items()
            if v and v != 1
        )
        c.print(f"train it: neo train {escape(str(self.data))}{flags} --out <scene folder>")
