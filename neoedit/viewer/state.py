"""What the viewer's page shows, without the page: the scene's versions, the version shown
(loaded versions cached), the last query, the pending (previewed) edit, and the render of
any camera with the current display settings. Thread-safe: the page's callbacks and the
render loops of every open page call in from their own threads.

A *preview* is the edit rendered at once, with no training, through the render-time edits
the library's previews use (``neo remove --no-inpaint``: the working box cut out of every
ray; ``neo move --preview``: the field composed under the motion); *commit* runs the full
edit (:func:`neoedit.edit.remove.remove`, :func:`neoedit.edit.relocate.move`, with the
configured settings) and writes a new version: into the store, or for a plain scene folder
into a new folder beside it.
"""

from __future__ import annotations

import dataclasses
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from neoedit.edit.pipeline import sketch
from neoedit.edit.relocate import Motion, MoveConfig, PreviewMove
from neoedit.edit.remove import Remove, RemoveConfig
from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox, motion_about
from neoedit.language.localize import QueryConfig, QueryResult, query_scene
from neoedit.language.relevancy import split_prompts
from neoedit.scene import Scene, load_scene, read_scene_meta
from neoedit.storage import SceneStore, find_store, is_store
from neoedit.storage.store import MANIFEST
from neoedit.viewer.render_loop import RenderLoopConfig
from neoedit.viewer.versions import VersionEntry, commit_edit, plain_entries, store_entries
from neoedit.viewer.view import ScanView, render_display, scan_views

Display = Literal["rgb", "depth"]


@dataclass
class ViewerConfig:
    query: QueryConfig = field(default_factory=QueryConfig)
    """How a prompt is found (as ``neo query``)."""
    remove: RemoveConfig = field(default_factory=RemoveConfig)
    """How a committed removal is made (as ``neo remove``); its preview only cuts the box."""
    move: MoveConfig = field(default_factory=MoveConfig)
    """How a committed move is made (as ``neo move``); its preview is composed at render time."""
    loop: RenderLoopConfig = field(default_factory=RenderLoopConfig)
    """Streaming: frame rate while the camera moves, delay before refining."""
    max_side: int = 640
    """Longest side of a full-resolution frame (the page's canvas is scaled down to it)."""
    cached_versions: int = 3
    """Versions kept loaded in memory."""


@dataclass
class PendingEdit:
    """An edit previewed on the version shown, waiting to be committed (or discarded)."""

    kind: Literal["remove", "move"]
    box: OrientedBox
    prompt: str | None
    scene: Scene = field(repr=False)
    """The preview: the version shown with the edit applied at render time."""
    transform: np.ndarray | None = field(default=None, repr=False)
    """(4,4) world motion of a move."""
    target: OrientedBox | None = None
    """Where a move puts the working box."""


class ViewerState:
    """The scene a viewer serves: a scene folder, a store (its current version first) or a
    store version."""

    def __init__(
        self, path: Path, device: torch.device | str = "cpu", cfg: ViewerConfig | None = None
    ):
        self.cfg = cfg or ViewerConfig()
        self.device = torch.device(device)
        self.store, start = _open_source(Path(path))
        self._plain: dict[str, Path] = {} if self.store is not None else {start: Path(path)}
        self._cache: OrderedDict[str, Scene] = OrderedDict()
        self._lock = threading.RLock()
        self._commit_lock = threading.Lock()
        self.display: Display = "rgb"
        self.heatmap = True
        """Show the last query's relevancy over the render."""
        self.selected = start
        self.scene = self._load(start)
        self.query_result: QueryResult | None = None
        self._embeddings: tuple[torch.Tensor, torch.Tensor] | None = None
        self.pending: PendingEdit | None = None
        """(stage, fraction done) while a commit runs."""

    # -- versions -------------------------------------------------------------------------
    def versions(self) -> list[VersionEntry]:
        """Every version, oldest first (a plain folder: itself and what this page committed)."""
        if self.store is not None:
            return store_entries(self.store)
        with self._lock:  # a commit thread may add to it
            plain = dict(self._plain)
        return plain_entries(plain, self.selected)

    def path_of(self, name: str) -> Path:
        if self.store is not None:
            return self.store.root / self.store.find(name)
        if name not in self._plain:
            raise NeoError(f"no version {name!r} (versions: {', '.join(self._plain)})")
        return self._plain[name]

    def select(self, name: str) -> Scene:
        """Show version ``name`` (the query and any preview belong to the version before)."""
        self.path_of(name)  # a known version
        scene = self._load(name)
        with self._lock:
            self.selected, self.scene = name, scene
            self.query_result, self._embeddings, self.pending = None, None, None
        return scene

    def restore(self, name: str) -> str:
        """Make ``name`` the store's current version (undo); returns the version before."""
        if self.store is None:
            raise NeoError(
                "a plain scene folder has no current version to restore: open a scene store "
                "(neo plan --out makes one)"
            )
        if self.committing:
            raise NeoError("a commit is running: restore once it has finished")
        before = self.store.current or "-"
        self.store.set_current(self.store.find(name))
        return before

    def _load(self, name: str) -> Scene:
        with self._lock:
            if name in self._cache:
                self._cache.move_to_end(name)
                return self._cache[name]
        scene = load_scene(self.path_of(name), self.device)
        self._remember(name, scene)
        return scene

    def _remember(self, name: str, scene: Scene) -> None:
        with self._lock:
            self._cache[name] = scene
            self._cache.move_to_end(name)
            while len(self._cache) > max(self.cfg.cached_versions, 1):
                self._cache.popitem(last=False)

    # -- query ----------------------------------------------------------------------------
    def query(self, prompt: str) -> QueryResult:
        """Find the object ``prompt`` names in the version shown; :class:`NoMatch` when
        nothing matches (the previous result is cleared either way)."""
        from neoedit.language.text import load_text_encoder

        prompts = split_prompts(prompt)
        if not prompts:
            raise NeoError('empty prompt: say which object to find, e.g. "red mug"')
        if len(prompts) > 1:
            raise NeoError("the viewer edits one object at a time: give a single prompt")
        scene = self.scene
        if scene.meta.language is None:
            raise NeoError(f"version {self.selected} has no language field: it cannot be queried")
        with self._lock:
            self.query_result, self._embeddings, self.pending = None, None, None
        text = load_text_encoder(scene.meta.language.text)
        result = query_scene(scene, prompts[0], text, self.cfg.query)  # or NoMatch
        emb = text.encode([prompts[0], *self.cfg.query.canonical])
        with self._lock:
            if self.scene is scene:  # not another version meanwhile
                self.query_result, self._embeddings = result, (emb[0], emb[1:])
        return result

    def clear_query(self) -> None:
        with self._lock:
            self.query_result, self._embeddings, self.pending = None, None, None

    # -- edits ----------------------------------------------------------------------------
    def _found(self) -> tuple[Scene, QueryResult]:
        with self._lock:
            scene, result = self.scene, self.query_result
        if result is None:
            raise NeoError("find an object first: type what to edit and press Find")
        return scene, result

    def preview_remove(self) -> PendingEdit:
        """The removal of the found object, instantly: its working box cut out of the rays
        (sketched: :func:`~neoedit.edit.pipeline.sketch`; a commit inpaints it)."""
        scene, result = self._found()
        cfg = dataclasses.replace(self.cfg.remove, inpaint=False)
        preview = sketch(scene, Remove([result.box], cfg, result.prompt))
        return self._set_pending(scene, PendingEdit("remove", result.box, result.prompt, preview))

    def preview_move(self, translate_m: np.ndarray, yaw_deg: float) -> PendingEdit | None:
        """The move of the found object by ``translate_m`` and ``yaw_deg`` (about the vertical
        axis through its box), composed at render time (``neo move --preview``, sketched);
        None (no preview) for no motion."""
        scene, result = self._found()
        t = np.asarray(translate_m, dtype=np.float64).reshape(3)
        if not np.isfinite(t).all() or not np.isfinite(yaw_deg):
            raise NeoError("the translation and the yaw must be finite numbers")
        if np.abs(t).max() < 1e-6 and abs(yaw_deg) < 1e-6:
            self.discard_preview()
            return None
        transform = motion_about(np.asarray(result.box.center_m), t, float(yaw_deg))
        cfg = dataclasses.replace(self.cfg.move, reuse_removal_patch=False)  # trains nothing
        with torch.no_grad():
            preview = sketch(
                scene, PreviewMove([Motion(result.box, transform)], cfg, result.prompt)
            )
        target = OrientedBox.from_dict(preview.meta.moves[-1]["target"])
        edit = PendingEdit("move", result.box, result.prompt, preview, transform, target)
        return self._set_pending(scene, edit)

    def _set_pending(self, scene: Scene, edit: PendingEdit) -> PendingEdit:
        with self._lock:
            if self.scene is not scene:
                raise NeoError("another version was selected meanwhile: preview again")
            self.pending = edit
        return edit

    def discard_preview(self) -> None:
        with self._lock:
            self.pending = None

    @property
    def committing(self) -> bool:
        return self._commit_lock.locked()

    def commit(self, progress: Callable[[str, float], None] | None = None) -> str:
        """Run the pending edit in full on the version shown and write it as a new version
        (made current in a store); shows it; returns its name. ``progress(stage,
        fraction)`` follows the edit's stages. One commit at a time."""
        if not self._commit_lock.acquire(blocking=False):
            raise NeoError("a commit is already running: wait for it to finish")
        try:
            with self._lock:
                edit, parent, parent_name = self.pending, self.scene, self.selected
            if edit is None:
                raise NeoError("nothing to commit: preview a removal or a move first")

            def report(stage: str, fraction: float) -> None:
                if progress is not None:
                    progress(stage, fraction)

            name, out, child = commit_edit(
                self.store,
                self.path_of(parent_name),
                parent,
                edit,
                self.cfg.remove,
                self.cfg.move,
                report,
            )
            if self.store is None:
                with self._lock:
                    self._plain[name] = out
            self._remember(name, child)
            self.select(name)
            return name
        finally:
            self._commit_lock.release()

    # -- rendering ------------------------------------------------------------------------
    def shown(self) -> tuple[Scene, dict[str, Any]]:
        """The scene to render (the pending preview, else the version) and the display
        settings (mode, relevancy embeddings for the heat map or None)."""
        with self._lock:
            scene = self.pending.scene if self.pending is not None else self.scene
            overlay = self._embeddings if self.heatmap else None
            return scene, {"mode": self.display, "relevancy": overlay}

    def render(
        self,
        c2w: np.ndarray,
        fov_y: float,
        width: int,
        height: int,
        should_stop: Callable[[], bool] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """What the page shows from a camera (OpenGL camera-to-world, vertical field of
        view in radians): image (H,W,3) float in [0,1] (RGB with the relevancy heat map, or
        colour-mapped depth) and z-depth (H,W) in metres (inf where nothing is hit)."""
        scene, settings = self.shown()
        return render_display(scene, c2w, fov_y, width, height, settings, should_stop)

    def scan_views(self, limit: int | None = None) -> list[ScanView]:
        """The training cameras of the scan (at most ``limit``, spread over them)."""
        return scan_views(self.scene, limit)


def _open_source(path: Path) -> tuple[SceneStore | None, str]:
    """(store or None, name of the version to show first) of a viewer's scene argument."""
    if is_store(path):
        store = SceneStore(path)
        return store, store.current_dir().name
    if (path / MANIFEST).is_file():
        owner = find_store(path)
        if owner is None:
            raise NeoError(f"{path} is a store version outside its store (no store.json beside it)")
        owner.info(path.name)
        return owner, path.name
    read_scene_meta(path)  # a scene folder, or one clear error
    return None, path.resolve().name
