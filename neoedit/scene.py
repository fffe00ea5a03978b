"""A scene on disk: one version of (radiance field + occupancy grid + metadata).

Layout of a scene directory::

    scene.json            metadata: configs, scene box, background, training state, lineage
    field.safetensors     field weights and the occupancy grid (edited versions: also the
                          patches their local edits trained, ``patch{i}.*``)
    language.safetensors  language field weights + the surface point cloud queries run on
                          (only once a language field is trained)
    optimizer.safetensors Adam state (only while training may resume)

A version inside a scene store (:mod:`neoedit.storage`) holds ``scene.json`` and
``tensors.json`` instead of the ``.safetensors`` files: its tensors are blobs of the store,
most as deltas against its parent version.

Written atomically; configs are JSON, tensors safetensors (nothing is pickled).
"""

from __future__ import annotations

import dataclasses
import json
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import torch
from pydantic import BeforeValidator, TypeAdapter, ValidationError
from safetensors.torch import load_file, save_file

from neoedit.cameras.rays import CameraTensors
from neoedit.data.scan import ScanCameras, dataset_cameras, scan_from_record
from neoedit.errors import NeoError
from neoedit.fields.background import Background
from neoedit.fields.checks import check_finite, check_language, check_weights
from neoedit.fields.composed import moved_field
from neoedit.fields.language import LanguageField, LanguageFieldConfig, TextEncoderSpec
from neoedit.fields.language_map import LanguageMap
from neoedit.fields.patched import PatchedField
from neoedit.fields.radiance import Field, RadianceField, RadianceFieldConfig
from neoedit.fields.stored import field_tensors, load_parts, part_records, prefixed
from neoedit.fields.suppressed import with_removals
from neoedit.geometry import OrientedBox
from neoedit.records import EditRecord
from neoedit.rendering.occupancy import OccupancyGrid, OccupancyGridConfig
from neoedit.rendering.renderer import RenderConfig, render_image
from neoedit.scene_checks import check_scene_meta
from neoedit.storage import find_store, resolve_scene_dir
from neoedit.storage.store import MANIFEST
from neoedit.utils.io import atomic_directory, atomic_write_json
from neoedit.utils.optim import optimizer_tensors

FORMAT = "neoedit.scene/1"


@dataclass
class LanguageMeta:
    """How the language field of a scene was made (queries embed prompts with ``text``)."""

    field: LanguageFieldConfig
    text: TextEncoderSpec
    teacher: str
    """'labels', 'clip' or 'geometric' (+ '+dino' when a DINO head was trained)."""
    vocabulary: list[str] = dataclasses.field(default_factory=list)
    """Names the label teacher embedded (empty for image teachers)."""
    steps: int = 0
    seconds: float = 0.0
    loss: float = 0.0
    """Final mean cosine distance to the teacher on training surface points."""
    up: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0, 1.0])
    """World up axis used for boxes (z in NEO-Sim; checked against the cameras)."""
    cloud_rays_per_pixel: float = 0.0
    """Rays per training pixel whose surface points make the query cloud (after its
    subsampling); edits re-render edited boxes at this density. 0: not recorded (scenes
    trained before it was), estimated from the cloud's size."""
    maps: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    """The edits since the weights were trained, oldest first (``LanguageMap.to_dict``): the
    field looks points up through them (a distilled update bakes them into its weights)."""


@dataclass
class SceneMeta:
    data_path: str
    """Dataset the scene was trained on (its cameras are reused by render/eval)."""
    aabb_m: list[list[float]]
    background_rgb: list[float]
    field: RadianceFieldConfig = dataclasses.field(default_factory=RadianceFieldConfig)
    grid: OccupancyGridConfig = dataclasses.field(default_factory=OccupancyGridConfig)
    render: RenderConfig = dataclasses.field(default_factory=RenderConfig)
    train: dict[str, Any] = dataclasses.field(default_factory=dict)
    step: int = 0
    train_seconds: float = 0.0
    history: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    """Training log: step, seconds, train/eval PSNR."""
    language: LanguageMeta | None = None
    scan: dict[str, Any] | None = None
    """The scan's cameras (poses, intrinsics, sizes, file names, splits): a version renders
    and edits without its dataset (scenes written before this field read ``data_path``)."""
    moves: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    """Render-time moves of a preview version (``neo move --preview``): per move the source
    and target boxes and the 4x4 world ``transform``; the source is emptied and the target
    shows the field under the inverse motion, with no training."""
    cut_boxes: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    """Boxes cut out of every ray at render time (removal by resampling, no training)."""
    suppress_boxes: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    """Boxes whose density is zeroed at render time (DFF-style suppression baseline)."""
    patches: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    """Local edits in the weights: ``{"region": [boxes], "version": id}`` per patch field,
    which answers for every point inside its boxes (later patches over earlier ones)."""
    shades: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    """Shadows laid on the field by moves: ``{"box": slab, "after": n, "version": id}`` per
    shade, its ratio map stored with the weights; it darkens what the base and the parts
    with an index below ``n`` answer in its slab (:mod:`neoedit.fields.shade`)."""
    edits: list[Annotated[EditRecord, BeforeValidator(EditRecord.parse)]] = dataclasses.field(
        default_factory=list
    )
    """Edit history from the original scan to this version, oldest first (stored as flat
    JSON objects: :meth:`to_dict`)."""
    version_id: str = dataclasses.field(default_factory=lambda: uuid.uuid4().hex[:12])
    parent: str | None = None
    created: str = dataclasses.field(default_factory=lambda: time.strftime("%Y-%m-%dT%H:%M:%S"))
    format: str = FORMAT

    def to_dict(self) -> dict[str, Any]:
        """The JSON object of scene.json (each edit record flat, as :class:`EditRecord`
        stores it)."""
        out = dataclasses.asdict(self)
        out["edits"] = [r.to_dict() for r in self.edits]
        return out


@dataclass
class Scene:
    field: RadianceField | PatchedField
    """The radiance field; a :class:`PatchedField` once local edits were trained."""
    grid: OccupancyGrid
    meta: SceneMeta
    language: LanguageField | None = None
    surface_points_m: torch.Tensor | None = None
    """(P,3) surface points seen in the training views (where queries evaluate L(x))."""

    @property
    def background(self) -> Background:
        """What rays meet outside the box: the field's room or learned environment map when
        it has one, else the constant background colour (3,)."""
        base = self.field.base if isinstance(self.field, PatchedField) else self.field
        head = getattr(base, "background_head", None)
        if head is not None:
            return head
        return torch.tensor(
            self.meta.background_rgb, dtype=torch.float32, device=self.field.aabb.device
        )

    def patched(self) -> PatchedField:
        """The field as a :class:`PatchedField` (wrapping it on first use) so an edit can
        add a patch (``meta.patches`` follows the field when the scene is saved)."""
        if not isinstance(self.field, PatchedField):
            self.field = PatchedField(self.field)
        return self.field

    def renderable(self) -> tuple[Field, list[OrientedBox]]:
        """The field to render and the boxes to cut out of every ray, with this version's
        render-time removals applied (suppression wraps the field; resampling cuts rays)."""
        field_: Field = self.field
        for move in self.meta.moves:  # preview moves compose over the field, in order
            field_ = moved_field(
                field_,
                field_,
                [OrientedBox.from_dict(move["source"])],
                [OrientedBox.from_dict(move["target"])],
                np.asarray(move["transform"], dtype=np.float64),
            )
        return with_removals(
            field_,
            cut=[OrientedBox.from_dict(b) for b in self.meta.cut_boxes],
            suppress=[OrientedBox.from_dict(b) for b in self.meta.suppress_boxes],
        )

    def scan_cameras(self) -> ScanCameras:
        """(cameras, file paths, splits) of the scan this version descends from."""
        if self.meta.scan is not None:
            return scan_from_record(self.meta.scan)
        try:
            return dataset_cameras(Path(self.meta.data_path))
        except (NeoError, OSError) as e:
            raise NeoError(
                f"this scene stores no cameras and its dataset {self.meta.data_path} cannot be "
                f"read ({e}); re-train it with this version of neoedit"
            ) from None

    def render_image(
        self, cameras: CameraTensors, index: int, height: int, width: int
    ) -> dict[str, torch.Tensor]:
        """rgb (H,W,3), depth_z (H,W) [m], accumulation (H,W) of one camera, as this version
        renders (render-time removals included)."""
        field_, boxes = self.renderable()
        return render_image(
            field_,
            self.grid,
            cameras,
            index,
            height,
            width,
            self.meta.render,
            self.background,
            boxes,
        )

    @classmethod
    def create(cls, meta: SceneMeta, device: torch.device | str = "cpu", seed: int = 0) -> Scene:
        aabb = torch.tensor(meta.aabb_m, dtype=torch.float32)
        field_ = RadianceField(meta.field, aabb, seed=seed).to(device)
        grid = OccupancyGrid(meta.grid, aabb).to(device)
        return cls(field_, grid, meta)


def save_scene(
    path: Path,
    scene: Scene,
    optimizer: torch.optim.Optimizer | None = None,
    extras: Callable[[Path], None] | None = None,
) -> None:
    """Write (or atomically replace) a scene directory. ``extras(folder)`` writes more
    files into it (an edit's report) before it is published, so they appear with it.

    A ``path`` inside a scene store (:mod:`neoedit.storage`) becomes a new version of the
    store: stored as deltas against its parent when that is in the store, and made current.
    The scene's tensors are then set to what was stored (bit-identical to a reload)."""
    path = Path(path)
    _sync_patches(scene)
    groups = _scene_groups(scene)
    for tensors in groups.values():  # a diverged edit never replaces a good version
        check_finite(tensors, path)
    store = find_store(path)
    if store is not None:
        if optimizer is not None:
            raise NeoError(f"{path}: training writes a plain scene folder, not a store version")
        stored = store.write(path.name, groups, scene.meta.to_dict(), extras)
        _apply_groups(scene, stored, path)
        return
    with atomic_directory(path, overwrite=True, kind="scene") as tmp:
        save_file(groups["field"], str(tmp / "field.safetensors"))
        if optimizer is not None:
            save_file(optimizer_tensors(scene.field, optimizer), str(tmp / "optimizer.safetensors"))
        if "language" in groups:
            save_file(groups["language"], str(tmp / "language.safetensors"))
        atomic_write_json(tmp / "scene.json", scene.meta.to_dict())
        if extras is not None:
            extras(tmp)


def _sync_patches(scene: Scene) -> None:
    """``meta.patches`` and ``meta.shades`` from the field (parts added since loading belong
    to this version); ``meta.language.maps`` from the language field."""
    meta = scene.meta
    if meta.language is not None and scene.language is not None:
        meta.language.maps = [m.to_dict() for m in scene.language.maps]
    meta.patches, meta.shades = part_records(
        scene.field, meta.patches, meta.shades, meta.version_id
    )


def _scene_groups(scene: Scene) -> dict[str, dict[str, torch.Tensor]]:
    """The tensors of a version: 'field' (weights, patches, occupancy grid) and, with a
    language field, 'language' (its weights and the query point cloud)."""
    field_ = field_tensors(scene.field)
    field_["grid.density"] = scene.grid.density.detach().cpu().contiguous()
    field_["grid.n_updates"] = scene.grid.n_updates.detach().cpu().reshape(1)
    groups = {"field": field_}
    if scene.language is not None and scene.surface_points_m is not None:
        lang = {
            f"language.{k}": v.detach().cpu().contiguous()
            for k, v in scene.language.state_dict().items()
        }
        lang["surface_points_m"] = scene.surface_points_m.detach().cpu().float().contiguous()
        groups["language"] = lang
    return groups


def read_scene_meta(path: Path) -> SceneMeta:
    """The validated metadata (scene.json) of a scene folder or store version."""
    meta_path = path / "scene.json"
    if path.is_file():
        raise NeoError(f"{path} is a file: give a scene folder (neo train --out writes one)")
    if not path.is_dir():
        raise NeoError(f"scene not found: {path}")
    if not meta_path.is_file():
        raise NeoError(f"{path} is not a neoedit scene (no scene.json)")
    try:
        raw = json.loads(meta_path.read_text())
    except (ValueError, RecursionError, OSError) as e:
        raise NeoError(f"{meta_path} is not valid JSON: {e}") from None
    if not isinstance(raw, dict) or raw.get("format") != FORMAT:
        raise NeoError(
            f"{meta_path}: unsupported scene format {raw.get('format') if isinstance(raw, dict) else None!r} (expected {FORMAT})"
        )
    try:
        meta = TypeAdapter(SceneMeta).validate_python(raw)
    except ValidationError as e:
        raise NeoError(
            f"{meta_path}: malformed metadata: {e.errors()[0]['loc']}: {e.errors()[0]['msg']}"
        ) from None
    check_scene_meta(meta, meta_path)
    return meta


def _read_files(path: Path, meta: SceneMeta) -> dict[str, dict[str, torch.Tensor]]:
    """The tensor groups of a plain scene folder (field.safetensors, language.safetensors)."""
    weights = path / "field.safetensors"
    if not weights.is_file():
        raise NeoError(f"{path}: missing field.safetensors")
    try:
        groups = {"field": load_file(str(weights))}
    except Exception as e:  # safetensors raises its own error types for corrupt files
        raise NeoError(f"{weights}: cannot read weights: {e}") from None
    if meta.language is not None:
        check_language(meta, path, None)
        file = path / "language.safetensors"
        if not file.is_file():
            raise NeoError(
                f"{path}: scene.json names a language field but language.safetensors is missing"
            )
        try:
            groups["language"] = load_file(str(file))
        except Exception as e:  # corrupt file
            raise NeoError(f"{file}: cannot load the language field: {e}") from None
    return groups


def load_scene(path: Path, device: torch.device | str = "cpu") -> Scene:
    """A scene folder, a version of a scene store, or a store (its current version)."""
    path = resolve_scene_dir(Path(path))
    meta = read_scene_meta(path)
    store = find_store(path) if (path / MANIFEST).is_file() else None
    if (path / MANIFEST).is_file() and store is None:
        raise NeoError(f"{path} is a store version outside its store (no store.json beside it)")
    groups = store.tensors(path.name) if store is not None else _read_files(path, meta)
    check_weights(meta, groups["field"], path / "field.safetensors")  # before any allocation
    scene = Scene.create(meta, device="cpu")
    _apply_groups(scene, groups, path)
    scene.field.to(device)
    scene.grid.to(device)
    if scene.language is not None:
        scene.language.to(device)
        scene.surface_points_m = scene.surface_points_m.to(device)  # type: ignore[union-attr]
    return scene


def _apply_groups(scene: Scene, groups: dict[str, dict[str, torch.Tensor]], path: Path) -> None:
    """Load the tensor groups into ``scene`` (its field, patches, grid and language field)."""
    meta, tensors = scene.meta, groups["field"]
    weights = path / "field.safetensors"  # checked by load_scene before the scene was built
    device = scene.field.aabb.device
    try:
        base = scene.field.base if isinstance(scene.field, PatchedField) else scene.field
        base.load_state_dict(prefixed(tensors, "field."))  # type: ignore[union-attr]
        if meta.patches or meta.shades:
            load_parts(scene.patched(), meta.patches, meta.shades, tensors)
        scene.grid.density.copy_(tensors["grid.density"])
        scene.grid.n_updates.copy_(tensors["grid.n_updates"][0])
        scene.grid.refresh_mask()
    except (RuntimeError, KeyError, ValueError) as e:
        raise NeoError(f"{weights}: weights do not match the scene config: {e}") from None
    if meta.language is not None:
        if "language" not in groups:
            raise NeoError(f"{path}: scene.json names a language field but it is not stored")
        _load_language(path, scene, meta.language, groups["language"])
        check_language(meta, path, scene)
        scene.language.to(device)  # type: ignore[union-attr]
        scene.surface_points_m = scene.surface_points_m.to(device)  # type: ignore[union-attr]
    scene.field.to(device)


def _load_language(
    path: Path, scene: Scene, meta: LanguageMeta, tensors: dict[str, torch.Tensor]
) -> None:
    file = path / "language.safetensors"
    try:
        field_ = LanguageField(meta.field, scene.field.aabb.cpu())
        field_.load_state_dict(
            {
                k.removeprefix("language."): v
                for k, v in tensors.items()
                if k.startswith("language.")
            }
        )
        points = tensors["surface_points_m"].clone()  # never the store's cached tensor
    except Exception as e:  # corrupt file, missing keys, shape mismatch
        raise NeoError(f"{file}: cannot load the language field: {e}") from None
    where = path / "scene.json"  # its maps were checked with the rest of it (scene_checks)
    field_.maps = [
        LanguageMap.from_dict(m, f"{where}: language.maps[{i}]") for i, m in enumerate(meta.maps)
    ]
    scene.language, scene.surface_points_m = field_, points
