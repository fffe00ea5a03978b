"""``neo remove``: a new scene version without an object (resampling + inpainting)."""

from __future__ import annotations

import contextlib
import dataclasses
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import tyro
from rich.console import Console
from rich.markup import escape

from neoedit.bench.seal3d import Seal3dConfig, SealMove
from neoedit.edit.history import edit_lock
from neoedit.edit.language_update import LanguageUpdateConfig
from neoedit.edit.relocate import MoveConfig, check_move_config, preview_ignored
from neoedit.edit.remove import RemoveConfig
from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox
from neoedit.language.localize import QueryConfig
from neoedit.scene import Scene
from neoedit.utils.options import spelt
from neoedit.utils.userfile import read_data_file

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
    masks: Path | None = None
    """Folder of 2-D masks of the object (non-zero = the object; e.g. SAM's), each named
    after a photo of the scan, instead of a prompt: the box is where the field's surface
    under the masks lies."""
    edit: Annotated[RemoveConfig, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=RemoveConfig
    )
    """(Its options are spelt without ``edit.``; its groups keep their names:
    ``--refine.steps``, ``--shadow.no-enabled``, ``--views.turns``.)"""
    query: QueryConfig = dataclasses.field(default_factory=QueryConfig)
    language: LanguageUpdateConfig = dataclasses.field(default_factory=LanguageUpdateConfig)
    """How the language field follows the removal (``--language.method distil``: the
    paper's distilled update instead of the parent's field read through the edit's map)."""
    json: Path | None = None
    """Also write the result here as JSON (the new version, its parent, the boxes, seconds
    and timings of every stage)."""
    overwrite: bool = False
    """Replace OUT if it exists (never the input scene), and an existing --json file that
    holds JSON that is no dataset or scene file."""
    report: bool = True
    """Render the before/after pictures under OUT/report/ (--no-report: the new version
    alone, seconds sooner, e.g. in a robot's loop of edits)."""
    device: str = "auto"

    def run(self) -> None:
        self.query.check()  # before any loading or training
        self.edit.check()
        self.language.check("--language")
        from neoedit.edit.pipeline import apply_edit
        from neoedit.edit.remove import Remove
        from neoedit.scene import save_scene

        with edit_session(self, (self.scene, self.box, self.masks)) as (scene, boxes):
            removal = Remove(boxes, self.edit, self.prompt, language=self.language)
            child = apply_edit(scene, removal)
            save_scene(
                self.out, child, extras=report_writer(self.report, scene, child, removal.strips)
            )
        write_result(self.json, self.out, child, self.report)
        rec = child.meta.edits[-1]
        console.print(
            f"wrote {self.out} (version {child.meta.version_id}, parent {child.meta.parent}) in "
            f"{rec.seconds or 0:.1f} s" + pictures_note(self.out, self.report),
            markup=False,
        )


@contextlib.contextmanager
def edit_session(
    cmd: RemoveCommand | MoveCommand, inputs: tuple[Path | None, ...]
) -> Iterator[tuple[Scene, list[OrientedBox]]]:
    """What every edit command does before its edit, holding OUT's writer lock: its --json
    output checked against ``inputs``, the scene loaded (:func:`start_edit`) and the
    object's boxes found (by prompt, box file or masks)."""
    check_json_output(cmd.json, cmd.out, inputs, cmd.overwrite)
    with edit_lock(cmd.out):
        target = (cmd.prompt, cmd.box, cmd.masks)
        scene = start_edit(cmd.scene, cmd.out, target, cmd.overwrite, cmd.device)
        yield scene, find_boxes(scene, cmd.prompt, cmd.box, cmd.query, cmd.masks)


def start_edit(
    scene_dir: Path,
    out: Path,
    target: tuple[str | None, Path | None, Path | None],
    overwrite: bool,
    device: str,
) -> Scene:
    """The checks every edit makes before any work (exactly one ``target`` of prompt / box
    file / masks folder; an output that is not the input and may be written), then the
    scene, loaded once."""
    from neoedit.edit.history import check_output
    from neoedit.scene import load_scene
    from neoedit.utils.device import resolve_device

    given = sum(t is not None for t in target)
    if given != 1:
        raise NeoError(
            'give one of a prompt ("red mug"), --box BOX.json or --masks FOLDER'
            + (", not two" if given > 1 else ": none was given")
        )
    if target[2] is not None and not Path(target[2]).is_dir():
        raise NeoError(f"--masks {target[2]}: not a folder")  # before the scene loads
    check_output(scene_dir, out, overwrite)
    return load_scene(scene_dir, resolve_device(device))


def check_json_output(
    path: Path | None, out: Path, inputs: tuple[Path | None, ...], overwrite: bool
) -> None:
    """A --json result file may be written: not an input, not inside OUT (a scene), and
    an existing file only with --overwrite (checked before any work)."""
    from neoedit.utils.io import check_writable_output

    if path is None:
        return
    out_r = out.resolve()
    if out_r == path.resolve() or out_r in path.resolve().parents:
        raise NeoError(f"{path} is inside the output {out}: write the --json file beside it")
    check_writable_output(path, [*inputs, out], "json", overwrite)


def edit_result(out: Path, child: Scene, report: bool = True) -> dict:
    """What a script wants to know about a new version: where it is, its place in the
    history, its edit's record (boxes, method, seconds, timings; not the full config) and
    its pictures' folder (None with --no-report)."""
    record = _without_config(child.meta.edits[-1].to_dict())
    if isinstance(record.get("edits"), list):  # a batch: its edits' records alike
        record["edits"] = [_without_config(e) for e in record["edits"] if isinstance(e, dict)]
    return {
        "out": str(out),
        "version_id": child.meta.version_id,
        "parent": child.meta.parent,
        "edit": record,
        "report": str(out / "report") if report else None,
    }


def _without_config(record: dict) -> dict:
    return {k: v for k, v in record.items() if k != "config"}


def write_result(path: Path | None, out: Path, child: Scene, report: bool = True) -> None:
    from neoedit.utils.io import atomic_write_json

    if path is not None:
        atomic_write_json(path, edit_result(out, child, report))


def pictures_note(out: Path, report: bool) -> str:
    return f"; pictures in {out / 'report'}" if report else ""


def report_writer(
    on: bool, parent: Scene, child: Scene, strips: list | None = None
) -> Callable[[Path], None] | None:
    """What writes an edit's pictures into its new version's folder (FOLDER/report/:
    before/after and the virtual views' ``strips``), or None with --no-report."""
    from neoedit.edit.remove import write_report

    return (lambda d: write_report(d / "report", parent, child, strips or [])) if on else None


def find_boxes(
    scene: Scene,
    prompt: str | None,
    box: Path | None,
    query: QueryConfig,
    masks: Path | None = None,
) -> list[OrientedBox]:
    """The boxes an edit works on: from a box file, from 2-D masks of the object, or one
    per prompt (``;`` separates several) found by the scene's language field."""
    from neoedit.geometry.box import load_boxes
    from neoedit.language.localize import find_objects

    if box is not None:
        return load_boxes(box)  # remove() / move() check them before any work
    if masks is not None:
        from neoedit.data.masks import read_object_masks
        from neoedit.edit.points import box_from_masks

        cameras, paths, _ = scene.scan_cameras()
        found = box_from_masks(scene, cameras, read_object_masks(masks, paths, cameras))
        console.print(f"masks in {escape(str(masks))}: box {json.dumps(found.to_dict())}")
        return [found]
    boxes = []
    for res in find_objects(scene, prompt or "", query):
        console.print(
            f"{escape(repr(res.prompt))}: box {json.dumps(res.box.to_dict())} (score {res.score:.3f})"
        )
        boxes.append(res.box)
    return boxes


@dataclass
class MoveCommand:
    """Move an object named by a prompt (or given as a box) to a new pose; writes a new scene
    version (the input is never modified) with before/after renders under OUT/report/.
    The motion is --translate X Y Z [--yaw DEG] (world metres; yaw about the vertical axis
    through the box centre) or --transform T.json (a 4x4 world transform, x' = T x)."""

    scene: tyro.conf.Positional[Path]
    """Scene directory to edit."""
    out: Path
    """New scene version to write."""
    prompt: tyro.conf.Positional[str | None] = None
    """What to move, e.g. "red mug" (needs a language field); or use --box."""
    box: Path | None = None
    """JSON box file ({"center", "size", "yaw_deg"}) instead of a prompt."""
    masks: Path | None = None
    """Folder of 2-D masks of the object, each named after a photo of the scan, instead of
    a prompt (see ``neo remove --masks``)."""
    translate: tuple[float, float, float] | None = None
    """Translation in metres, world frame."""
    yaw: float = 0.0
    """Rotation in degrees about the vertical axis through the box centre (with --translate,
    or alone)."""
    transform: Path | None = None
    """JSON file with a 4x4 world-frame rigid transform (list of 4 rows), or an object with a
    "transform_world" key (NEO-Sim's scene.json action format)."""
    method: Literal["neo", "seal3d"] = "neo"
    """'neo' (the paper: region-composed teachers, inpainted source) or 'seal3d' (the
    single-teacher baseline, set with --seal3d.*)."""
    preview: bool = False
    """Instant preview: record the move and render it by composition, no training."""
    edit: MoveConfig = dataclasses.field(default_factory=MoveConfig)
    """Everything else of NEO's edit (--edit.distill.render-steps, --edit.remove.inpainter, ...)."""
    seal3d: Seal3dConfig = dataclasses.field(default_factory=Seal3dConfig)
    """The baseline's settings, with --method seal3d (--seal3d.schedule.render-steps ...)."""
    query: QueryConfig = dataclasses.field(default_factory=QueryConfig)
    json: Path | None = None
    """Also write the result here as JSON (the new version, its parent, the source and
    target boxes, the transforms, seconds and timings)."""
    overwrite: bool = False
    """Replace OUT if it exists (never the input scene), and an existing --json file that
    holds JSON that is no dataset or scene file."""
    report: bool = True
    """Render the before/after pictures under OUT/report/ (--no-report: the new version
    alone, seconds sooner, e.g. in a robot's loop of edits)."""
    device: str = "auto"

    def run(self) -> None:
        self.query.check()  # before any loading or training
        check_move_method(self.method, self.preview, self.edit, self.seal3d, "--edit")
        from neoedit.edit.pipeline import Edit, apply_edit
        from neoedit.edit.relocate import Motion, Move, PreviewMove
        from neoedit.scene import save_scene

        transform = self.motion()
        inputs = (self.scene, self.box, self.masks, self.transform)
        with edit_session(self, inputs) as (scene, boxes):
            motions = [Motion(b, motion_for(b, transform)) for b in boxes]
            edit: Edit = (
                SealMove(motions, self.seal3d, self.prompt)
                if self.method == "seal3d"
                else PreviewMove(motions, self.edit, self.prompt)
                if self.preview
                else Move(motions, self.edit, self.prompt)
            )
            child = apply_edit(scene, edit)
            save_scene(self.out, child, extras=report_writer(self.report, scene, child))
        write_result(self.json, self.out, child, self.report)
        rec = child.meta.edits[-1]
        console.print(
            f"wrote {self.out} ({rec.method}, version {child.meta.version_id}, parent "
            f"{child.meta.parent}) in {rec.seconds or 0:.1f} s"
            + pictures_note(self.out, self.report),
            markup=False,
        )

    def motion(self) -> np.ndarray | tuple[np.ndarray, float]:
        """A 4x4 transform (--transform) or (translation, yaw) to apply about each box."""
        if self.transform is not None:
            if self.translate is not None or self.yaw != 0.0:
                raise NeoError("give either --translate/--yaw or --transform, not both")
            return read_transform(self.transform)
        if self.translate is None and self.yaw == 0.0:
            raise NeoError("say where to: --translate X Y Z [--yaw DEG] or --transform T.json")
        t = np.asarray(self.translate if self.translate is not None else (0.0, 0.0, 0.0))
        if not np.isfinite(t).all() or not np.isfinite(self.yaw):
            raise NeoError("--translate and --yaw must be finite numbers")
        if abs(self.yaw) > 360.0:
            raise NeoError(f"--yaw is in degrees, within [-360, 360]; got {self.yaw:g}")
        return t, float(self.yaw)


def motion_for(box: OrientedBox, motion: np.ndarray | tuple[np.ndarray, float]) -> np.ndarray:
    from neoedit.geometry import motion_about

    if isinstance(motion, tuple):
        return motion_about(np.asarray(box.center_m), motion[0], motion[1])
    return motion


def read_transform(path: Path) -> np.ndarray:
    """A 4x4 matrix from a JSON file: a list of 4 rows, or {"transform_world": rows}."""
    raw = read_data_file(Path(path), "transform file")
    if isinstance(raw, dict):
        raw = raw.get("transform_world", raw.get("transform"))
    try:
        t = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        t = np.zeros(0)
    if t.shape != (4, 4):
        raise NeoError(f"{path}: expected a 4x4 matrix (a JSON list of 4 rows of 4 numbers)")
    from neoedit.edit.motion import check_rigid

    check_rigid(t, f"{path}: the transform")  # before the scene loads and the query runs
    return t


def check_move_method(
    method: str, preview: bool, neo: MoveConfig, seal3d: Seal3dConfig, where: str
) -> None:
    """Refuse, before any work, settings the chosen method would ignore or cannot run with:
    NEO's options (``where``.*) with the Seal-3D-style baseline, --seal3d.* with NEO, a
    preview of the baseline."""
    if method == "seal3d":
        if preview:
            raise NeoError("--preview and --method seal3d do not combine: a preview trains nothing")
        if neo != MoveConfig():
            raise NeoError(
                f"{where}.* options set NEO's move; with --method seal3d set the baseline with "
                "--seal3d.* (e.g. --seal3d.margin-m, --seal3d.schedule.render-steps)"
            )
        seal3d.check()
        return
    if seal3d != Seal3dConfig():
        raise NeoError(
            "--seal3d.* options set the Seal-3D-style baseline: add --method seal3d, or set "
            f"NEO's move with {where}.*"
        )
    ignored = preview_ignored(neo) if preview else []
    if ignored:
        names = ", ".join(spelt(where, n.replace("_", "-")) for n in ignored)
        raise NeoError(
            f"a preview trains nothing: {names} would be ignored (drop "
            f"{'it' if len(ignored) == 1 else 'them'}, or move without --preview)"
        )
    check_move_config(neo, where)
