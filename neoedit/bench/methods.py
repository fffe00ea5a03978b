"""The methods of the paper's tables and how one of them runs on one scene.

Removal (Table I): the pre-edit field, resampling only, DFF-style density suppression,
NEO (resampling + multiview-consistent progressive inpainting), the NeRFiller-style
baseline with and without depth, the Seal-3D-style baseline and an oracle trained on the
post scan. Pick-and-place (Tables II, III): the pre-edit field, the composite preview,
NEO, the Seal-3D-style baseline, the ablations and the oracle. Assembly: the four moves,
each from the previous version, by NEO and by the Seal-3D-style baseline; oracles per step.

Every method finds its object with a query of the object's name on the pre scene (as a
user would), and is evaluated on the post scan's held-out views with ``neo eval``'s
metrics over Full, Out (the true source box's silhouette), In (the true target box's) and
Rest.

Each row that edits is a typed edit run by :func:`~neoedit.edit.pipeline.apply_edit`: NEO's
:class:`~neoedit.edit.remove.Remove`, :class:`~neoedit.edit.relocate.Move` and
:class:`~neoedit.edit.relocate.PreviewMove` in their configurations (resampling only and the
ablations change one part of NEO's configuration), and the baselines' own classes beside
this module (:mod:`~neoedit.bench.dff`, :mod:`~neoedit.bench.seal3d`,
:mod:`~neoedit.bench.nerfiller`).
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from neoedit.bench.dff import DffRemove
from neoedit.bench.seal3d import Seal3dConfig, SealMove, SealRemove
from neoedit.cameras.rays import CameraTensors
from neoedit.data import SceneData, load_scene_data
from neoedit.edit.language_update import LanguageUpdateConfig
from neoedit.edit.pipeline import Edit, apply_edit
from neoedit.edit.relocate import Motion, Move, MoveConfig, PreviewMove, check_motions
from neoedit.edit.remove import Remove, RemoveConfig
from neoedit.errors import NeoError
from neoedit.eval.evaluate import evaluate
from neoedit.eval.footprint import removal_footprint
from neoedit.geometry import OrientedBox
from neoedit.geometry.box import box_iou_3d
from neoedit.language.localize import NoMatch, QueryConfig, query_scene
from neoedit.language.text import load_text_encoder
from neoedit.scene import Scene, load_scene, save_scene
from neoedit.storage import SceneStore

REMOVAL_METHODS = (
    "pre-edit",
    "resample",
    "suppress",
    "neo",
    "nerfiller",
    "nerfiller-no-depth",
    "seal3d",
    "oracle",
)
MOVE_METHODS = ("pre-edit", "preview", "neo", "seal3d", "oracle")
NO_EDIT = ("pre-edit", "oracle")
"""Rows that edit nothing: the pre scene as it is, and a field trained on the post scan."""
NEO_REMOVALS = ("neo", "resample")
"""Table I's rows that are NEO's own removal (the baselines are their own edits: DFF-style
suppression :class:`~neoedit.bench.dff.DffRemove`, Seal-3D-style
:class:`~neoedit.bench.seal3d.SealRemove`, NeRFiller-style
``neoedit.bench.nerfiller.NerfillerRemove``); the removal ablations are NEO's too."""
ABLATIONS: dict[str, Callable[[MoveConfig], MoveConfig]] = {
    "no-virtual-views": lambda c: dataclasses.replace(c, virtual_views=False),
    "no-grid-inpaint": lambda c: dataclasses.replace(
        c,
        remove=dataclasses.replace(
            c.remove, refine=dataclasses.replace(c.remove.refine, grid=False)
        ),
    ),
    "no-mask-cond": lambda c: dataclasses.replace(
        c,
        remove=dataclasses.replace(
            c.remove, refine=dataclasses.replace(c.remove.refine, mask_conditioned=False)
        ),
    ),
    "field-distill-only": lambda c: dataclasses.replace(c, field_only=True),
    "no-shadow": lambda c: dataclasses.replace(
        c,
        remove=dataclasses.replace(
            c.remove, shadow=dataclasses.replace(c.remove.shadow, enabled=False)
        ),
    ),
    "no-shadow-follow": lambda c: dataclasses.replace(c, shadow_follows=False),
    "distil-target": lambda c: dataclasses.replace(c, carry=False),
    "no-relight": lambda c: dataclasses.replace(c, relight=False),
}
REMOVAL_ABLATIONS: dict[str, Callable[[RemoveConfig], RemoveConfig]] = {
    "remove-no-shadow": lambda c: dataclasses.replace(
        c, shadow=dataclasses.replace(c.shadow, enabled=False)
    ),
    "remove-no-grid-inpaint": lambda c: dataclasses.replace(
        c, refine=dataclasses.replace(c.refine, grid=False)
    ),
    "inpaint-telea": lambda c: dataclasses.replace(c, inpainter="telea"),
    "inpaint-ns": lambda c: dataclasses.replace(c, inpainter="ns"),
}
"""NEO's removal with one part changed (Table I's ablations, on the removal scenes): the
shadow search off, views inpainted one by one instead of in 2x2 composites, OpenCV's
Telea or Navier-Stokes inpainter instead of FSR."""
ASSEMBLY_METHODS = ("neo", "seal3d", "oracle")
ALL_METHODS = tuple(
    dict.fromkeys((*REMOVAL_METHODS, *REMOVAL_ABLATIONS, *MOVE_METHODS, *ABLATIONS))
)

LABELS = {
    "pre-edit": "pre-edit field (object still there)",
    "resample": "resampling only (no inpainting)",
    "suppress": "DFF-style suppression",
    "neo": "**NEO**",
    "nerfiller": "NeRFiller-style",
    "nerfiller-no-depth": "NeRFiller-style w/o depth",
    "seal3d": "Seal-3D-style",
    "preview": "composite preview (no training)",
    "oracle": "oracle (trained on the post scan)",
    "no-virtual-views": "w/o virtual view distillation",
    "no-grid-inpaint": "w/o 2x2 grid inpainting",
    "no-mask-cond": "w/o mask-conditioned training",
    "field-distill-only": "field distillation only",
    "no-shadow": "w/o shadow removal at the source (nor laid at the target)",
    "no-shadow-follow": "shadow removed at the source, not laid at the target",
    "distil-target": "moved object distilled (the paper's student), not carried",
    "no-relight": "carried object keeps the scan's shading (not relit)",
    "remove-no-shadow": "w/o the shadow search (the object's shadow stays)",
    "remove-no-grid-inpaint": "w/o 2x2 grid inpainting (each view alone)",
    "inpaint-telea": "Telea inpainter (OpenCV) instead of FSR",
    "inpaint-ns": "Navier-Stokes inpainter (OpenCV) instead of FSR",
}


def _steps(n: int, scale: float) -> int:
    return max(int(round(n * scale)), 1) if n > 0 else 0


def language_config(scale: float = 1.0) -> LanguageUpdateConfig:
    """How the language field follows every edit: NEO's default (composed; before 2026-12-07
    distilled), the paper's distilled update's steps multiplied by ``scale``."""
    cfg = LanguageUpdateConfig()
    cfg.steps = _steps(cfg.steps, scale)
    return cfg


def remove_config(method: str, scale: float = 1.0) -> RemoveConfig:
    """NEO's removal configuration for 'neo', 'resample' (NEO without its inpainting: the
    box cut out of the rays at render time) or a removal ablation (which changes one part);
    ``scale`` multiplies the training steps (the small profile's budget)."""
    cfg = RemoveConfig()
    cfg.refine.steps = _steps(cfg.refine.steps, scale)
    if method in REMOVAL_ABLATIONS:
        return REMOVAL_ABLATIONS[method](cfg)
    if method not in NEO_REMOVALS:
        known = ", ".join((*NEO_REMOVALS, *REMOVAL_ABLATIONS))
        raise NeoError(f"{method!r} is not a configuration of NEO's removal (choose from {known})")
    return cfg if method == "neo" else dataclasses.replace(cfg, inpaint=False)


def move_config(method: str, scale: float = 1.0) -> MoveConfig:
    """NEO's move configuration for 'neo', 'preview' (which uses its margins and language
    update) or an ablation (which changes one part); ``scale`` multiplies every training
    step count."""
    base = MoveConfig()
    base.remove.refine.steps = _steps(base.remove.refine.steps, scale)
    d = base.distill
    d.field_steps, d.render_steps = _steps(d.field_steps, scale), _steps(d.render_steps, scale)
    base.language = language_config(scale)
    if method in ABLATIONS:
        return ABLATIONS[method](base)
    return base


def seal3d_config(scale: float = 1.0) -> Seal3dConfig:
    """The Seal-3D-style baseline's configuration, its steps multiplied by ``scale``."""
    cfg = Seal3dConfig()
    d = cfg.schedule
    d.field_steps, d.render_steps = _steps(d.field_steps, scale), _steps(d.render_steps, scale)
    cfg.language = language_config(scale)
    return cfg


def move_edit(method: str, motions: list[Motion], scale: float, prompt: str) -> Edit:
    """The typed edit of one pick-and-place method: the Seal-3D-style baseline's, NEO's
    preview, or NEO's (the ablations are configurations of it)."""
    if method == "seal3d":
        return SealMove(motions, seal3d_config(scale), prompt)
    if method == "preview":
        return PreviewMove(motions, move_config(method, scale), prompt)
    if method not in ("neo", *ABLATIONS):
        known = ", ".join(("neo", "preview", "seal3d", *ABLATIONS))
        raise NeoError(f"unknown move method {method!r} (choose from {known})")
    return Move(motions, move_config(method, scale), prompt)


@dataclasses.dataclass(frozen=True)
class SceneInputs:
    """What a method unit reads: the scene's suite folder and its trained scans."""

    data: Path
    """The simulated scene: scene.json, pre/, post/ or post_1.. ."""
    pre: Path | None
    """The pre scan's trained scene (with language)."""
    oracles: dict[str, Path]
    """Post scan name -> its trained oracle scene."""
    eval_views: int | None
    seed: int
    query: QueryConfig = dataclasses.field(default_factory=QueryConfig)
    edit_scale: float = 1.0
    """Multiplies the training steps of every edit (see :class:`~neoedit.bench.profiles.Budget`)."""
    keep: Path | None = None
    """Where to save the edited version (the assembly: a scene store of its chain, step_0 the
    pre scene); None: the version is evaluated and dropped."""


class Refusal(NeoError):
    """The method cannot run on this scene, an outcome of the method rather than a fault:
    the object's name finds nothing, or its found box moved by the action leaves the scene."""


def found_box(pre: Scene, name: str, cfg: QueryConfig) -> OrientedBox:
    """The box ``neo query`` finds for ``name`` (a Refusal when it finds nothing)."""
    text = load_text_encoder(pre.meta.language.text)  # type: ignore[union-attr]
    try:
        return query_scene(pre, name, text, cfg).box
    except NoMatch as e:
        raise Refusal(str(e)) from e


def checked_motion(scene: Scene, box: OrientedBox, transform: list) -> Motion:
    """The action's motion of the found box; a Refusal when it cannot be applied."""
    motion = Motion(box, np.asarray(transform, dtype=np.float64))
    try:
        check_motions(scene, [motion])
    except NeoError as e:
        raise Refusal(str(e)) from e
    return motion


def render_view(scene: Scene, data: SceneData) -> np.ndarray:
    """The scene at the first held-out camera of ``data`` (uint8), for the figure strips."""
    view = int(data.split["test"][0])
    rgb = scene.render_image(CameraTensors(data.cameras), view, data.height, data.width)["rgb"]
    return (rgb.clamp(0, 1).numpy() * 255).round().astype(np.uint8)


def removal_edit(
    method: str, box: OrientedBox, inp: SceneInputs, name: str, scan: SceneData | None
) -> Edit:
    """The typed edit of one removal method of Table I (run by :func:`apply_edit`): NEO's
    removal in one of its configurations (:data:`NEO_REMOVALS`, the removal ablations) or a
    baseline's edit (DFF-, Seal-3D-, NeRFiller-style), each with the bench's language update."""
    language = language_config(inp.edit_scale)
    if method in (*NEO_REMOVALS, *REMOVAL_ABLATIONS):
        return Remove([box], remove_config(method, inp.edit_scale), name, language=language)
    if method == "suppress":
        return DffRemove([box], name, language=language)
    if method == "seal3d":
        return SealRemove([box], seal3d_config(inp.edit_scale), name)
    if method not in ("nerfiller", "nerfiller-no-depth"):
        known = ", ".join(m for m in (*REMOVAL_METHODS, *REMOVAL_ABLATIONS) if m not in NO_EDIT)
        raise NeoError(f"{method!r} is not a removal method that edits (choose from {known})")
    from neoedit.bench.nerfiller import NerfillerConfig, NerfillerRemove

    # NeRFiller retrains the whole field: the pre scan's own budget, edit_scale or not
    # (its language update is scaled as every method's)
    cfg = NerfillerConfig(depth=method == "nerfiller", seed=inp.seed)
    if scan is None:
        raise NeoError("the NeRFiller-style baseline needs the pre scan's images")
    return NerfillerRemove(scan, [box], cfg, name, language=language)


def run_removal(method: str, inp: SceneInputs) -> tuple[dict[str, Any], np.ndarray]:
    """One removal method on one scene -> (metrics row, figure tile)."""

    def edit(pre: Scene, box: OrientedBox, action: dict) -> Callable[[], Scene]:
        # the scan's images (NeRFiller-style retraining) are read before the clock starts
        scan = load_scene_data(inp.data / "pre") if method.startswith("nerfiller") else None
        removal = removal_edit(method, box, inp, action["object"], scan)
        return lambda: apply_edit(pre, removal)

    return _run_action(method, inp, edit, moved=False)


def run_move(method: str, inp: SceneInputs) -> tuple[dict[str, Any], np.ndarray]:
    """One pick-and-place method (or ablation) on one scene -> (metrics row, figure tile)."""

    def edit(pre: Scene, box: OrientedBox, action: dict) -> Callable[[], Scene]:
        motion = checked_motion(pre, box, action["transform_world"])
        relocation = move_edit(method, [motion], inp.edit_scale, action["object"])
        return lambda: apply_edit(pre, relocation)

    return _run_action(method, inp, edit, moved=True)


TimedEdit = Callable[[Scene, OrientedBox, dict], Callable[[], Scene]]
"""(pre scene, found box, action) -> the timed edit (what it needs is prepared untimed)."""


def _run_action(
    method: str, inp: SceneInputs, edit: TimedEdit, moved: bool
) -> tuple[dict[str, Any], np.ndarray]:
    """The scene's one action by ``method``: the pre scene as it is ('pre-edit'), the
    oracle, or ``edit`` of the box found for the object's name; evaluated on the post scan
    over Out (the true source box), In (the true target box, when ``moved``) and the rest."""
    action = json.loads((inp.data / "scene.json").read_text())["actions"][0]
    source = OrientedBox.from_dict(action["source_box"])
    targets = [OrientedBox.from_dict(action["target_box"])] if moved else []
    post = load_scene_data(inp.data / "post")
    row: dict[str, Any] = {"object": action["object"]}
    if method == "oracle":
        scene = load_scene(inp.oracles["post"])
        row["seconds"] = round(scene.meta.train_seconds, 1)
    else:
        pre = load_scene(_need(inp.pre))
        if method == "pre-edit":
            scene, row["seconds"] = pre, None
        else:
            box = found_box(pre, action["object"], inp.query)
            row["query_iou"] = round(box_iou_3d(box, source), 3)
            timed = edit(pre, box, action)
            t0 = time.perf_counter()
            scene = timed()
            row["seconds"] = round(time.perf_counter() - t0, 1)
            if moved:
                row["query_after_iou"] = _found_iou(scene, action["object"], targets[0], inp)
            if inp.keep is not None:
                save_scene(inp.keep, scene)
    row.update(evaluate(scene, post, "test", [source], targets, max_views=inp.eval_views))
    row["footprint_delta"] = _footprint(scene, source, targets)
    return row, render_view(scene, post)


def _footprint(scene: Scene, box: OrientedBox, targets: list[OrientedBox]) -> float | None:
    """How far the support where the object stood differs in colour from the ring around
    it, as the scene's scan cameras see it (largest channel, 0-255; the ring left out under
    a move's target; None when no camera sees it)."""
    try:
        return removal_footprint(scene, box, exclude=targets).delta
    except NeoError:
        return None


def _found_iou(scene: Scene, name: str, truth: OrientedBox, inp: SceneInputs) -> float:
    """IoU with ``truth`` of the box the object's name finds on an edited version (0 when
    nothing is found): does the language field follow the object to its new place?"""
    try:
        return round(box_iou_3d(found_box(scene, name, inp.query), truth), 3)
    except Refusal:
        return 0.0


def run_assembly(method: str, inp: SceneInputs) -> tuple[dict[str, Any], np.ndarray]:
    """The four moves of the assembly, each from the previous version (oracle: each post
    scan's own field) -> ({"steps": rows}, a tile per step side by side)."""
    actions = json.loads((inp.data / "scene.json").read_text())["actions"]
    chain = None if method == "oracle" else load_scene(_need(inp.pre))
    store = None
    if chain is not None and inp.keep is not None:
        store = SceneStore.create(inp.keep)
        save_scene(store.root / "step_0", chain)
    rows: list[dict[str, Any]] = []
    tiles = []
    for k, action in enumerate(actions, 1):
        post = load_scene_data(inp.data / f"post_{k}")
        source = OrientedBox.from_dict(action["source_box"])
        target = OrientedBox.from_dict(action["target_box"])
        row: dict[str, Any] = {"step": k, "object": action["object"]}
        if chain is None:
            current = load_scene(inp.oracles[f"post_{k}"])
            row["seconds"] = round(current.meta.train_seconds, 1)
        else:
            try:
                box = found_box(chain, action["object"], inp.query)
                motion = checked_motion(chain, box, action["transform_world"])
            except Refusal as e:  # the chain cannot go on; the steps so far are kept
                rows.append({**row, "error": str(e)})
                break
            row["query_iou"] = round(box_iou_3d(box, source), 3)
            t0 = time.perf_counter()
            chain = apply_edit(chain, move_edit(method, [motion], inp.edit_scale, action["object"]))
            row["seconds"] = round(time.perf_counter() - t0, 1)
            current = chain
            if store is not None:
                save_scene(store.root / f"step_{k}", chain)
                row["store_mb"] = round(store.size_bytes() / 1e6, 1)
        row.update(evaluate(current, post, "test", [source], [target], max_views=inp.eval_views))
        rows.append(row)
        tiles.append(render_view(current, post))
    strip = np.concatenate(tiles, axis=1) if tiles else np.zeros((8, 8, 3), np.uint8)
    return {"steps": rows}, strip


RUNNERS = {"removal": run_removal, "pick_place": run_move, "assembly": run_assembly}


def _need(path: Path | None) -> Path:
    if path is None:
        raise NeoError("this method needs the trained pre scan")
    return path
