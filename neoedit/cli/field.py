"""``neo train``, ``neo render`` and ``neo eval``."""

from __future__ import annotations

import contextlib
import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro
from rich.console import Console
from rich.markup import escape

from neoedit.data.downscale import DataConfig
from neoedit.errors import NeoError
from neoedit.fields.radiance import RadianceFieldConfig
from neoedit.language.training import LanguageTrainConfig
from neoedit.rendering.occupancy import OccupancyGridConfig
from neoedit.rendering.renderer import RenderConfig
from neoedit.training.trainer import TrainConfig
from neoedit.utils.options import at_least_one

console = Console()


@dataclass
class TrainCommand:
    """Train a scene (radiance field) on a dataset (nerfstudio transforms.json or Blender)."""

    data: tyro.conf.Positional[Path]
    """Dataset folder."""
    out: Path
    """Scene directory to write (checkpointed atomically during training)."""
    data_cfg: Annotated[DataConfig, tyro.conf.OmitArgPrefixes] = dataclasses.field(
        default_factory=DataConfig
    )
    train: Annotated[TrainConfig, tyro.conf.OmitArgPrefixes] = dataclasses.field(
        default_factory=TrainConfig
    )
    field: RadianceFieldConfig = dataclasses.field(default_factory=RadianceFieldConfig)
    grid: OccupancyGridConfig = dataclasses.field(default_factory=OccupancyGridConfig)
    render: RenderConfig = dataclasses.field(default_factory=RenderConfig)
    language: LanguageTrainConfig = dataclasses.field(default_factory=LanguageTrainConfig)
    """Language field, trained after the radiance field on the frozen geometry."""
    skip_language: bool = False
    """Do not train the language field (scenes without one cannot be queried)."""
    device: str = "auto"
    """'auto' (CUDA if available), 'cpu' or 'cuda[:N]'."""
    resume: bool = False
    """Continue training the scene in OUT up to --max-steps (with --max-steps at or below the
    steps already done, only the language field is (re)trained)."""

    def run(self) -> None:
        from neoedit.training.trainer import train

        self.check()
        scene = train(
            self.data,
            self.out,
            self.train,
            self.field,
            self.render,
            self.grid,
            self.device,
            self.resume,
            None if self.skip_language else self.language,
            self.data_cfg,
        )
        last = scene.meta.history[-1] if scene.meta.history else {}
        console.print(
            f"wrote {self.out}: {scene.meta.step} steps in {scene.meta.train_seconds:.1f} s "
            f"({last.get('rays_per_s', 0) / 1e3:.1f}k rays/s), train PSNR {last.get('train_psnr')} dB, held-out PSNR {last.get('eval_psnr')} dB",
            markup=False,
        )
        lang = scene.meta.language
        if lang is not None:
            console.print(
                f"language field ({lang.teacher}, {lang.field.dim}-d): {lang.steps} steps in "
                f"{lang.seconds:.1f} s, cosine loss {lang.loss:.4f}"
            )

    def check(self) -> None:
        """Everything that can be refused before the data is read and training starts."""
        from neoedit.training.checks import check_train_options
        from neoedit.utils.io import check_writable_output

        language = None if self.skip_language else self.language
        self.data_cfg.check()
        check_train_options(self.train, self.field, self.grid, self.render, language, self.resume)
        check_writable_output(
            self.out, [self.data], "scene", self.resume, "pass --resume to continue it"
        )
        if self.resume and language is None:
            done = _steps_done(self.out)
            if done is not None and self.train.max_steps <= done:
                raise NeoError(
                    f"{self.out} already has {done} steps and --skip-language is set: nothing "
                    "to do (raise --max-steps)"
                )


def _steps_done(scene_dir: Path) -> int | None:
    try:
        step = json.loads((scene_dir / "scene.json").read_text()).get("step")
    except (OSError, ValueError, AttributeError):
        return None
    return step if isinstance(step, int) else None


@dataclass
class RenderCommand:
    """Render a scene: its training or held-out views, a spiral video, or the cameras of a transforms.json."""

    scene: tyro.conf.Positional[Path]
    """Scene directory."""
    out: Path
    """Output folder (a nerfstudio dataset: images/, depth/ in mm, depth_vis/, transforms.json)."""
    views: Literal["train", "eval", "spiral"] = "eval"
    """Which cameras: the training data's train or held-out split, or a spiral around the scene."""
    cameras: Path | None = None
    """Render exactly the frames of this transforms.json, each under its own file_path (overrides --views)."""
    n_frames: int = at_least_one(60)
    """Frames of the spiral."""
    video: bool = False
    """Also write video.gif (and video.mp4 if imageio-ffmpeg is installed)."""
    device: str = "auto"
    overwrite: bool = False
    """Replace OUT if it holds an earlier render (never anything else)."""

    def run(self) -> None:
        from neoedit.export import render_command

        n = render_command(
            self.scene,
            self.out,
            self.views,
            self.cameras,
            self.n_frames,
            self.video,
            self.device,
            overwrite=self.overwrite,
        )
        console.print(f"wrote {n} views to {escape(str(self.out))}")


@dataclass
class EvalCommand:
    """PSNR, SSIM, depth RMSE and E_rep of a scene against ground-truth views (Full / Out / In)."""

    scene: tyro.conf.Positional[Path]
    """Scene directory."""
    data: Path
    """Ground-truth dataset (e.g. the post-manipulation scan)."""
    data_cfg: Annotated[DataConfig, tyro.conf.OmitArgPrefixes] = dataclasses.field(
        default_factory=DataConfig
    )
    json: Path | None = None
    """Write the metrics here as JSON."""
    split: Literal["test", "train", "all"] = "test"
    """Which frames of DATA to compare against."""
    out_box: Path | None = None
    """Box JSON ({"center","size","yaw_deg"}, or a list of them): the 'Out' region (object moved out)."""
    in_box: Path | None = None
    """Box JSON: the 'In' region (object moved in)."""
    images: Path | None = None
    """Write rendered|ground-truth side-by-side images here (a new folder)."""
    align_poses: bool = False
    """Fit each evaluated camera's pose to its photo first (the field frozen; 200 steps of
    512 pixels a photo; the --out-box / --in-box pixels left out; the JSON's 'aligned' says
    by how much): the fair measure of a field trained with --pose-refinement, whose
    training photos moved into agreement while the held-out ones kept the dataset's poses."""
    device: str = "auto"
    overwrite: bool = False
    """Replace the --images folder if it holds earlier evaluation images, and an existing
    --json file that holds JSON that is no dataset or scene file (never anything else)."""

    def run(self) -> None:
        from neoedit.data import load_scene_data
        from neoedit.eval.align import AlignConfig
        from neoedit.eval.evaluate import evaluate
        from neoedit.geometry.box import load_boxes
        from neoedit.scene import load_scene
        from neoedit.utils.device import resolve_device
        from neoedit.utils.io import atomic_directory, atomic_write_json, check_writable_output

        inputs = [self.scene, self.data, self.out_box, self.in_box]
        if self.json:
            check_writable_output(self.json, inputs, "json", self.overwrite)
        if self.images:
            check_writable_output(
                self.images, inputs, "eval-images", self.overwrite, option="--images"
            )
        scene = load_scene(self.scene, resolve_device(self.device))
        data = load_scene_data(self.data, self.data_cfg)
        out_boxes = load_boxes(self.out_box) if self.out_box else []
        in_boxes = load_boxes(self.in_box) if self.in_box else []
        with (
            atomic_directory(self.images, self.overwrite, "eval-images")
            if self.images
            else contextlib.nullcontext()
        ) as image_dir:
            align = AlignConfig() if self.align_poses else None
            result = evaluate(scene, data, self.split, out_boxes, in_boxes, image_dir, align=align)
        if self.json:
            atomic_write_json(self.json, result)
        console.print_json(json.dumps(result))
        for region, option in (("out", "--out-box"), ("in", "--in-box")):
            if region in result and result[region]["psnr"] is None:
                Console(stderr=True).print(
                    f"warning: {option} covers no pixel of the {result['n_views']} views: its "
                    "metrics are null (is the box inside the scene, in front of the cameras?)",
                    markup=False,
                )
