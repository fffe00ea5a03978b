"""``neo query``: prompt -> oriented 3-D box, relevancy maps and a render with the box."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tyro
from rich.console import Console
from rich.markup import escape

from neoedit.errors import NeoError
from neoedit.language.localize import QueryConfig
from neoedit.utils.io import check_writable_output, default_output, mark_output
from neoedit.utils.validate import user_message

console = Console()


@dataclass
class QueryCommand:
    """Find the object a prompt names; prints its box as JSON (the box format of objects.json)
    and writes a picture per view: the render with the box, the relevancy map. Several prompts
    are separated by ';'. A prompt that matches nothing exits with status 1 (its relevancy map
    is still drawn: where it scored best)."""

    scene: tyro.conf.Positional[Path]
    """Scene directory (with a language field)."""
    prompt: tyro.conf.Positional[str]
    """What to find, e.g. "red mug" or "red mug; duck"."""
    json: Path | None = None
    """Also write the box (one prompt; no file when it matches nothing) or the list of boxes
    (several prompts: one entry each, in order, null where a prompt matched nothing)."""
    out: Path | None = None
    """Folder for query.png (default: a new outputs/query/<scene name>-<prompt>[-N])."""
    views: int = 3
    """Training views to draw (0 = no pictures)."""
    image_scale: float = 0.5
    """Resolution of the pictures relative to the training images."""
    query: QueryConfig = dataclasses.field(default_factory=QueryConfig)
    overwrite: bool = False
    """Replace an existing --json file (a previous JSON result, never a dataset or scene
    file) and the pictures in an --out folder an earlier query wrote."""
    device: str = "auto"

    def run(self) -> None:
        self.query.check()  # before any loading or training
        from neoedit.language.localize import NoMatch, query_scene
        from neoedit.language.relevancy import split_prompts
        from neoedit.language.text import load_text_encoder
        from neoedit.scene import load_scene
        from neoedit.utils.device import resolve_device
        from neoedit.utils.io import atomic_write_json

        prompts = split_prompts(self.prompt)
        if not prompts:
            raise NeoError('empty prompt: say which object to find, e.g. "red mug"')
        if not 0 < self.image_scale <= 4:
            raise NeoError(f"--image-scale must be in (0, 4], got {self.image_scale}")
        self._check_outputs()
        scene = load_scene(self.scene, resolve_device(self.device))
        if scene.meta.language is None:
            raise NeoError(f"{self.scene} has no language field (train it on data with a teacher)")
        text = load_text_encoder(scene.meta.language.text)
        results, misses = [], []
        found: list[dict | None] = []  # one entry per prompt, None for a miss
        for prompt in prompts:
            try:
                results.append(query_scene(scene, prompt, text, self.query))
                found.append(results[-1].to_dict())
            except NoMatch as e:
                misses.append(e)
                found.append(None)
        for box in found:
            if box is not None:
                console.print_json(json.dumps(box))
        if self.views:  # a prompt that matched nothing too: where it scored, without a box
            path = self._pictures(scene, results, prompts, text)
            if path is not None:
                console.print(f"wrote {escape(str(path))}")
        if self.json is not None and (len(prompts) > 1 or not misses):
            # several prompts: one entry each, in order, null where nothing matched
            atomic_write_json(self.json, found[0] if len(prompts) == 1 else found)
        if misses:
            err = Console(stderr=True)
            for miss in misses:
                err.print(f"[bold red]error:[/] {user_message(miss)}", highlight=False)
            raise SystemExit(1)

    def _pictures(self, scene, results, prompts, text) -> Path | None:
        from neoedit.language.report import write_query_images

        try:
            cameras, _, split = scene.scan_cameras()
        except NeoError as e:
            console.print(
                f"[yellow]no pictures: the scene's dataset cannot be read ({escape(str(e))})[/]"
            )
            return None
        train = split["train"]
        pick = train[
            np.linspace(0, len(train) - 1, min(self.views, len(train))).round().astype(int)
        ]
        cams = cameras.subset(pick).scaled(self.image_scale)
        out = self._pictures_dir()
        path = write_query_images(scene, results, prompts, text, cams, out, self.query)
        mark_output(out, "query")  # a later query may update this folder's picture
        return path

    def _pictures_dir(self) -> Path:
        if self.out is None:  # derived once per call: the check and the writing agree
            self.out = default_output("query", self.scene, self.prompt)
        return self.out

    def _check_outputs(self) -> None:
        """With --overwrite, --json may replace an earlier JSON result and --out an earlier
        query's pictures; nothing else, and never inside the scene."""
        if self.json is not None:
            check_writable_output(self.json, [self.scene], "json", self.overwrite)
        if self.views:
            check_writable_output(self._pictures_dir(), [self.scene], "query", self.overwrite)
