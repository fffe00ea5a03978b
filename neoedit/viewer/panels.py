"""The viewer page's controls (viser GUI): versions, display, query, edit and commit, and
the found box with its move gizmo in the 3-D scene."""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from neoedit.geometry import yaw_of_rotation
from neoedit.geometry.transforms import wrap_deg
from neoedit.language.localize import QueryResult
from neoedit.utils.threads import apply_thread_budget
from neoedit.viewer.versions import versions_markdown
from neoedit.viewer.view import quat_to_matrix, yaw_quat

if TYPE_CHECKING:
    from neoedit.viewer.app import ViewerServer

FOUND = (255, 40, 40)
TARGET = (40, 220, 90)


class Panels:
    """Every control of the page; the callbacks act on the app's state and re-render."""

    def __init__(self, app: ViewerServer):
        self.app, self.state = app, app.state
        gui = app.server.gui
        self._box: Any = None
        self._target: Any = None
        self._gizmo: Any = None
        self._reported = 0.0
        self.status = gui.add_markdown(
            f"Showing **{self.state.selected}**. Drag to orbit, scroll to zoom; click a grey "
            "frustum to look through that scan camera."
        )
        self._versions_panel()
        self._view_panel()
        self._find_panel()
        self._edit_panel()

    def say(self, text: str) -> None:
        """The status line at the top of the page."""
        self.status.content = text

    # -- versions -------------------------------------------------------------------------
    def _versions_panel(self) -> None:
        gui, guarded = self.app.server.gui, self.app.guarded
        entries = self.state.versions()
        with gui.add_folder("Versions"):
            self.version = gui.add_dropdown(
                "version", [e.name for e in entries], initial_value=self.state.selected
            )
            self.table = gui.add_markdown(versions_markdown(entries, self.state.selected))
            self.restore = gui.add_button(
                "Make current (restore)",
                disabled=self.state.store is None,
                hint="Undo: the store's current version becomes the one selected",
            )
        self.version.on_update(guarded("select")(self._select))
        self.restore.on_click(guarded("restore")(self._restore))

    def _select(self, _: Any) -> None:
        name = self.version.value
        if name == self.state.selected:
            return
        self.say(f"loading **{name}** ...")
        self.state.select(name)
        self.clear_found()
        self.update_versions()
        self.say(f"showing **{name}**")
        self.app.refresh()

    def _restore(self, event: Any) -> None:
        name = self.version.value
        before = self.state.restore(name)
        self.update_versions()
        self.say(f"current version: {before} -> **{name}**")
        self.app.notify(event.client, "restored", f"{name} is the current version")

    def update_versions(self) -> None:
        entries = self.state.versions()
        self.version.options = [e.name for e in entries]
        self.version.value = self.state.selected
        self.table.content = versions_markdown(entries, self.state.selected)

    # -- display --------------------------------------------------------------------------
    def _view_panel(self) -> None:
        gui, guarded = self.app.server.gui, self.app.guarded
        scan = self.app.scan
        fov = round(math.degrees(scan[0].fov_y)) if scan else 60
        with gui.add_folder("View"):
            self.show = gui.add_button_group("show", ("RGB", "Depth"))
            self.heatmap = gui.add_checkbox("relevancy heat-map", True)
            self.fov = gui.add_slider("field of view (deg)", 10, 120, 1, min(max(fov, 10), 120))
            self.home = gui.add_button("Back to the scan camera", disabled=not scan)
            self.save = gui.add_button("Save view as PNG")
        self.show.on_click(guarded("display")(self._show))
        self.heatmap.on_update(guarded("display")(self._heatmap))
        self.fov.on_update(guarded("field of view")(lambda _: self.app.set_fov(self.fov.value)))
        self.home.on_click(guarded("camera")(lambda e: self.app.go_to(e.client, scan[0])))
        self.save.on_click(guarded("save")(self._save))

    def _show(self, _: Any) -> None:
        self.state.display = "depth" if self.show.value == "Depth" else "rgb"
        self.app.refresh()

    def _heatmap(self, _: Any) -> None:
        self.state.heatmap = bool(self.heatmap.value)
        self.app.refresh()

    def _save(self, event: Any) -> None:
        client = event.client
        png = self.app.snapshot_png(None if client is None else client.client_id)
        name = f"{self.state.selected}_view.png"
        if client is not None:
            client.send_file_download(name, png, save_immediately=True)
        self.say(f"saved the view as {name} ({len(png) / 1024:.1f} kB)")

    # -- query ----------------------------------------------------------------------------
    def _find_panel(self) -> None:
        gui, guarded = self.app.server.gui, self.app.guarded
        with gui.add_folder("Query"):
            self.prompt = gui.add_text("prompt", "", hint='what to find, e.g. "red mug"')
            self.find = gui.add_button("Find")
            self.clear = gui.add_button("Clear")
        self.find.on_click(guarded("find")(self._find))
        self.clear.on_click(guarded("clear")(self._clear))

    def _find(self, _: Any) -> None:
        prompt = self.prompt.value.strip()
        self.clear_found()
        self.say(f"finding *{prompt}* ...")
        try:
            result = self.state.query(prompt)
        finally:
            self.app.refresh()  # the old box and heat map are gone either way
        self.show_found(result)
        c = ", ".join(f"{v:.3f}" for v in result.box.center_m)
        s = " x ".join(f"{v * 100:.1f}" for v in result.box.size_m)
        self.say(f"found *{prompt}* (score {result.score:.2f}): box at [{c}] m, {s} cm")

    def _clear(self, _: Any) -> None:
        self.state.clear_query()
        self.clear_found()
        self.say("cleared")
        self.app.refresh()

    def show_found(self, result: QueryResult) -> None:
        """The box (red wireframe), where a move puts it (green) and the move gizmo."""
        scene, box = self.app.server.scene, result.box
        q = yaw_quat(box.yaw_deg)
        self._box = scene.add_box(
            "/found/box",
            color=FOUND,
            dimensions=box.size_m,
            wireframe=True,
            position=box.center_m,
            wxyz=q,
        )
        self._target = scene.add_box(
            "/found/target",
            color=TARGET,
            dimensions=box.size_m,
            wireframe=True,
            position=box.center_m,
            wxyz=q,
            visible=False,
        )
        self._gizmo = scene.add_transform_controls(
            "/found/gizmo", scale=max(0.08, 1.5 * max(box.size_m)), position=box.center_m, wxyz=q
        )
        self._gizmo.on_update(self.app.guarded("move preview")(self._dragged))
        self.translate.value = (0.0, 0.0, 0.0)
        self.yaw.value = 0.0

    def clear_found(self) -> None:
        for handle in (self._box, self._target, self._gizmo):
            if handle is not None:
                handle.remove()
        self._box = self._target = self._gizmo = None

    # -- edits ----------------------------------------------------------------------------
    def _edit_panel(self) -> None:
        gui, guarded = self.app.server.gui, self.app.guarded
        with gui.add_folder("Edit"):
            self.remove = gui.add_button("Preview removal")
            self.translate = gui.add_vector3("translate (m)", (0.0, 0.0, 0.0), step=0.005)
            self.yaw = gui.add_number("yaw (deg)", 0.0, step=1.0)
            self.move = gui.add_button("Preview move", hint="or drag the gizmo on the box")
            self.discard = gui.add_button("Discard preview")
            self.commit = gui.add_button("Commit", color="green", hint="run the full edit")
            self.progress = gui.add_progress_bar(0.0, visible=False)
        self.remove.on_click(guarded("removal preview")(self._preview_remove))
        self.move.on_click(guarded("move preview")(self._preview_move))
        self.discard.on_click(guarded("discard")(self._discard))
        self.commit.on_click(guarded("commit")(lambda _: self._start_commit()))

    def _preview_remove(self, _: Any) -> None:
        edit = self.state.preview_remove()
        if self._target is not None:
            self._target.visible = False
        self.say(f"preview: *{edit.prompt}* removed (cut out, not inpainted); Commit runs it")
        self.app.refresh()

    def _preview_move(self, _: Any) -> None:
        t = np.asarray(self.translate.value, dtype=np.float64)
        yaw = float(self.yaw.value)
        edit = self.state.preview_move(t, yaw)
        result = self.state.query_result
        if result is not None and self._gizmo is not None and self._target is not None:
            position = np.asarray(result.box.center_m) + t
            q = yaw_quat(result.box.yaw_deg + yaw)
            self._gizmo.position, self._gizmo.wxyz = position, q
            self._target.position, self._target.wxyz = position, q
            self._target.visible = edit is not None
        if edit is None:
            self.say("no motion: nothing to preview")
        else:
            shift = ", ".join(f"{v:+.3f}" for v in t)
            self.say(
                f"preview: *{edit.prompt}* moved by [{shift}] m, {yaw:+.1f} deg; Commit runs it"
            )
        self.app.refresh()

    def _dragged(self, event: Any) -> None:
        """The gizmo: the green box follows it; on release, the move is previewed."""
        result = self.state.query_result
        if result is None or self._target is None:
            return
        gizmo = event.target
        t = [float(v) for v in np.subtract(gizmo.position, result.box.center_m)]
        yaw = wrap_deg(yaw_of_rotation(quat_to_matrix(gizmo.wxyz)) - result.box.yaw_deg)
        if event.phase != "end":
            self._target.position = gizmo.position
            self._target.wxyz = yaw_quat(result.box.yaw_deg + yaw)  # upright: yaw only
            self._target.visible = True
            return
        self.translate.value = (round(t[0], 4), round(t[1], 4), round(t[2], 4))
        self.yaw.value = round(yaw, 2)
        self._preview_move(event)

    def _discard(self, _: Any) -> None:
        self.state.discard_preview()
        result = self.state.query_result
        if result is not None and self._gizmo is not None and self._target is not None:
            self._gizmo.position = result.box.center_m
            self._gizmo.wxyz = yaw_quat(result.box.yaw_deg)
            self._target.visible = False
        self.translate.value, self.yaw.value = (0.0, 0.0, 0.0), 0.0
        self.say("preview discarded")
        self.app.refresh()

    def _start_commit(self) -> None:
        self.app.commit()
        self.say("committing: the full edit runs in the background; the page stays usable")

    def run_commit(self) -> None:
        """The commit thread's body: the full edit, its progress in the page, the new
        version listed and shown."""
        apply_thread_budget()
        self.commit.disabled = True
        self.restore.disabled = True
        self.progress.value = 0.0
        self.progress.visible = True
        try:
            self.app.guarded("commit")(self._commit_body)(None)
        finally:
            self.progress.visible = False
            self.commit.disabled = False
            self.restore.disabled = self.state.store is None
            self.app.refresh()

    def _commit_body(self, _: Any) -> None:
        pending = self.state.pending
        kind = pending.kind if pending is not None else "edit"
        name = self.state.commit(self._progressed)
        self.clear_found()
        self.update_versions()
        self.say(f"committed the {kind}: new version **{name}**, shown now")
        self.app.notify(None, "committed", f"new version {name}")

    def _progressed(self, stage: str, fraction: float) -> None:
        now = time.monotonic()
        if fraction < 1.0 and now - self._reported < 0.25:
            return  # a few updates a second are plenty
        self._reported = now
        self.progress.value = round(100.0 * fraction, 1)
        self.say(f"committing: {stage} ({100 * fraction:.0f} %)")
