"""``neo remove``: a new scene version without an object (resampling + inpainting)."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import tyro
from rich.console import Console

from neoedit.edit.remove import RemoveConfig
from neoedit.errors import NeoError
from neoedit.language.localize import QueryConfig

console = Console()


@dataclass
class RemoveCommand:
    """Remove an object named by a prompt (or given as a box) from a scene; writes a new scene
    version (the input is never modified) plus before/after renders and the virtual views of
    every inpainting round under OUT/report/."""

    scene: tyro.conf.Positional[Path]
    """Scene directory to edit."""
    out: Path
    """New scene version to write."""
    prompt: tyro.conf.Positional[str | None] = None
    """What to remove, e.g. "red mug" (needs a language field); or use --box."""
    box: Path | None = None
    """JSON box file ({"center", "size", "yaw_deg"}, or a list of them) instead of a prompt."""
    edit: tyro.conf.OmitArgPrefixes[RemoveConfig] = dataclasses.field(default_factory=RemoveConfig)
    query: QueryConfig = dataclasses.field(default_factory=QueryConfig)
    overwrite: bool = False
    """Replace OUT if it exists (never the input scene)."""
    device: str = "auto"

    def run(self) -> None:
        from neoedit.edit.remove import remove_object
        from neoedit.geometry.box import load_boxes
        from neoedit.language.localize import query_scene
        from neoedit.language.relevancy import split_prompts
        from neoedit.language.text import load_text_encoder
        from neoedit.scene import load_scene
        from neoedit.training.trainer import resolve_device

        device = resolve_device(self.device)
        if (self.prompt is None) == (self.box is None):
            raise NeoError('give either a prompt ("red mug") or --box BOX.json, not both')
        if self.box is not None:
            boxes = load_boxes(self.box)
            prompt = None
        else:
            prompts = split_prompts(self.prompt or "")
            if not prompts:
                raise NeoError('empty prompt: say which object to remove, e.g. "red mug"')
            scene = load_scene(self.scene, device)
            if scene.meta.language is None:
                raise NeoError(
                    f"{self.scene} has no language field: pass --box instead of a prompt"
                )
            text = load_text_encoder(scene.meta.language.text)
            boxes = []
            for p in prompts:
                res = query_scene(scene, p, text, self.query)
                console.print(f"{p!r}: box {json.dumps(res.box.to_dict())} (score {res.score:.3f})")
                boxes.append(res.box)
            prompt = self.prompt
        child = remove_object(
            self.scene, self.out, boxes, self.edit, prompt, device, self.overwrite
        )
        rec = child.meta.edits[-1]
        console.print(
            f"wrote {self.out} (version {child.meta.version_id}, parent {child.meta.parent}) in "
            f"{rec['seconds']:.1f} s; pictures in {self.out / 'report'}"
        )
