"""The Python facade: a scene loaded once and edited many times, in a few calls.

    import neoedit as neo

    s = neo.load("outputs/demo/scene")
    s2 = s.remove("red mug")                          # a new version; s is unchanged
    s3 = s2.move("duck", translate=(0.1, 0.0, 0.0))
    rgb = s3.render()                                 # (H, W, 3) uint8, a scan camera
    s4 = s.batch().remove("ball").move("mug", translate=(0.02, 0, 0)).apply()  # one version
    neo.save(s4, "outputs/demo/moved")

Each call is the library function the ``neo`` verbs use (:func:`neoedit.edit.remove.remove`,
:func:`neoedit.edit.relocate.move`, :class:`neoedit.edit.batch.Batch`,
:func:`neoedit.language.localize.find_objects`), with
their configs as keyword arguments; :attr:`EditableScene.scene` is the underlying
:class:`neoedit.scene.Scene` for everything else.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from neoedit.cameras import Cameras
from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox, motion_about
from neoedit.scene import Scene

Target = str | OrientedBox | Sequence[OrientedBox]
"""What an edit works on: a prompt ("red mug", "mug; duck") or boxes."""


@dataclass(frozen=True, repr=False)
class EditableScene:
    """A scene version with its edits as methods; every edit returns a new version."""

    scene: Scene
    source: Path | None = None
    """The folder the first version was loaded from (a save never writes over it)."""

    def __repr__(self) -> str:
        meta = self.scene.meta
        last = meta.edits[-1].label if meta.edits else "none"
        return (
            f"EditableScene(version={meta.version_id!r}, parent={meta.parent!r}, "
            f"edits={len(meta.edits)}, last edit={last!r}, source={self.source!s})"
        )

    def find(self, prompt: str, query=None) -> list[OrientedBox]:
        """The box of each object ``prompt`` names (``;`` separates several)."""
        from neoedit.language.localize import find_objects

        return [r.box for r in find_objects(self.scene, prompt, query)]

    def _boxes(self, target: Target, query) -> tuple[list[OrientedBox], str | None]:
        if isinstance(target, str):
            return self.find(target, query), target
        if isinstance(target, OrientedBox):
            return [target], None
        boxes = list(target) if isinstance(target, (list, tuple)) else []
        if not boxes or not all(isinstance(b, OrientedBox) for b in boxes):
            raise NeoError(
                f"give a prompt, a box or a list of boxes (neo.OrientedBox), not {target!r:.60}"
            )
        return boxes, None

    def remove(self, target: Target, cfg=None, query=None, language=None) -> EditableScene:
        """The scene without ``target``, what it hid inpainted (``cfg``: a RemoveConfig;
        ``language``: a LanguageUpdateConfig, how the language field follows)."""
        return self._apply(self._removal(target, cfg, query, language))

    def move(
        self,
        target: Target,
        translate: Sequence[float] = (0.0, 0.0, 0.0),
        yaw_deg: float = 0.0,
        cfg=None,
        query=None,
        preview: bool = False,
    ) -> EditableScene:
        """The scene with ``target`` moved by ``translate`` (world metres) and turned by
        ``yaw_deg`` about the vertical through its box centre (``cfg``: a MoveConfig;
        ``preview``: composed at render time, nothing trained, at once)."""
        return self._apply(self._motion(target, translate, yaw_deg, cfg, query, preview))

    def batch(self) -> BatchBuilder:
        """Several edits as one new version (one robot action that changes several
        objects), in separate places::

            s2 = s.batch().remove("soccer ball").move("mug", translate=(0.02, 0, 0)).apply()

        Each object is found on this version; the edits run in order on the new one, and
        its history gets one entry that lists them (:class:`neoedit.edit.batch.Batch`)."""
        return BatchBuilder(self)

    def _apply(self, edit) -> EditableScene:
        from neoedit.edit.pipeline import apply_edit

        return EditableScene(apply_edit(self.scene, edit), self.source)

    def _removal(self, target: Target, cfg, query, language=None):
        from neoedit.edit.language_update import LanguageUpdateConfig
        from neoedit.edit.remove import Remove, RemoveConfig

        _check_type(cfg, RemoveConfig, "cfg")
        _check_type(language, LanguageUpdateConfig, "language")
        boxes, prompt = self._boxes(target, query)
        return Remove(boxes, cfg or RemoveConfig(), prompt, language=language)

    def _motion(
        self,
        target: Target,
        translate: Sequence[float],
        yaw_deg: float,
        cfg,
        query,
        preview: bool,
    ):
        from neoedit.edit.relocate import Motion, Move, MoveConfig, PreviewMove

        _check_type(cfg, MoveConfig, "cfg")
        shift, yaw_deg = _motion_numbers(translate, yaw_deg)
        boxes, prompt = self._boxes(target, query)
        motions = [Motion(b, motion_about(np.asarray(b.center_m), shift, yaw_deg)) for b in boxes]
        kind = PreviewMove if preview else Move
        return kind(motions, cfg or MoveConfig(), prompt)

    def render(self, cameras: Cameras | None = None, index: int = 0) -> np.ndarray:
        """(H, W, 3) uint8 RGB of camera ``index`` of ``cameras`` (default: the scan's)."""
        from neoedit.viz.versions import render_rgb

        if cameras is None:
            cameras = self.scene.scan_cameras()[0]
        if not 0 <= index < len(cameras):
            raise NeoError(f"camera index {index} out of range (0..{len(cameras) - 1})")
        return render_rgb(self.scene, cameras, index)

    @property
    def cameras(self) -> Cameras:
        """The cameras of the scan the scene was trained on."""
        return self.scene.scan_cameras()[0]


def _check_type(value, kind: type, name: str) -> None:
    """``value`` is None or a ``kind`` (the facade's configs), else one clear NeoError."""
    if value is not None and not isinstance(value, kind):
        raise NeoError(f"{name} takes a neo.{kind.__name__}, not {type(value).__name__}")


def _motion_numbers(translate: Sequence[float], yaw_deg: float) -> tuple[np.ndarray, float]:
    """``translate`` as three finite metres and ``yaw_deg`` as a finite angle within
    [-360, 360] (the command line's rules), else one clear NeoError."""
    try:
        shift = np.asarray(translate, dtype=np.float64).reshape(3)
        yaw = float(yaw_deg)
    except (TypeError, ValueError):
        raise NeoError(
            f"translate takes three numbers (x, y, z) in metres and yaw_deg one number; got "
            f"{translate!r:.40} and {yaw_deg!r:.20}"
        ) from None
    if not (np.isfinite(shift).all() and np.isfinite(yaw)):
        raise NeoError("translate and yaw_deg must be finite numbers")
    if abs(yaw) > 360.0:
        raise NeoError(f"yaw_deg is in degrees, within [-360, 360]; got {yaw:g}")
    return shift, yaw


@dataclass
class BatchBuilder:
    """The edits of one batch, collected by :meth:`EditableScene.batch` (same arguments as
    the scene's own ``remove`` / ``move``) and applied together by :meth:`apply`."""

    scene: EditableScene
    edits: list = field(default_factory=list)

    def remove(self, target: Target, cfg=None, query=None) -> BatchBuilder:
        self.edits.append(self.scene._removal(target, cfg, query))
        return self

    def move(
        self,
        target: Target,
        translate: Sequence[float] = (0.0, 0.0, 0.0),
        yaw_deg: float = 0.0,
        cfg=None,
        query=None,
        preview: bool = False,
    ) -> BatchBuilder:
        self.edits.append(self.scene._motion(target, translate, yaw_deg, cfg, query, preview))
        return self

    def apply(self) -> EditableScene:
        """The new version with every collected edit (refused before any work when two
        touch the same place, or when some train and others are instant previews)."""
        from neoedit.edit.batch import Batch

        return self.scene._apply(Batch(list(self.edits)))


def load(path: str | Path, device: str = "auto") -> EditableScene:
    """A scene folder, a store version or a store (its current version)."""
    from neoedit.scene import load_scene
    from neoedit.utils.device import resolve_device

    return EditableScene(load_scene(Path(path), resolve_device(device)), Path(path))


def save(scene: EditableScene | Scene, out: str | Path, overwrite: bool = False) -> Path:
    """Write a version to a new folder (or as a new version, inside a store); never over
    its parent or an input. Returns the folder."""
    from neoedit.scene import save_scene
    from neoedit.utils.io import check_writable_output

    if not isinstance(scene, (EditableScene, Scene)):
        raise NeoError(f"save takes a scene (neo.load's, or an edit's), not {type(scene).__name__}")
    core = scene.scene if isinstance(scene, EditableScene) else scene
    source = scene.source if isinstance(scene, EditableScene) else None
    out = Path(out)
    check_writable_output(out, [Path(core.meta.data_path), source], "scene", overwrite)
    save_scene(out, core)
    return out
