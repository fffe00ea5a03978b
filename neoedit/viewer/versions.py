"""The versions a viewer lists, and the commit of a previewed edit as a new version.

A commit runs the library's full edit (as ``neo remove`` / ``neo move`` do, report
included) and publishes it: in a scene store as the next version (made current), for a
plain scene folder as a new folder beside it (the input is never modified). Its progress
is the progress bars of the edit's stages (inpainting, distillation, language update),
forwarded to the page while the commit runs.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from neoedit.edit.history import check_output, edit_lock
from neoedit.edit.pipeline import apply_edit
from neoedit.edit.relocate import Motion, Move, MoveConfig
from neoedit.edit.remove import Remove, RemoveConfig, write_report
from neoedit.errors import NeoError
from neoedit.records import own_edit
from neoedit.scene import Scene, save_scene
from neoedit.storage import SceneStore
from neoedit.utils.progress import progress_listener

if TYPE_CHECKING:
    from neoedit.viewer.state import PendingEdit

Report = Callable[[str, float], None]
"""(stage, fraction of the stage done)."""


@dataclass
class VersionEntry:
    name: str
    version_id: str
    parent: str
    """Name of the parent version where it is listed, else its id ('-' for none)."""
    edit: str
    """'train', 'remove', 'remove (cut)', 'move (neo)', 'move (preview)', ..."""
    prompt: str
    current: bool
    """The store's current version (a plain folder: the one shown)."""


def _entry(name: str, meta: dict[str, Any], parent: str, current: bool) -> VersionEntry:
    rec = own_edit(meta)
    edit, prompt = ("train", "") if rec is None else (rec.label, rec.prompt or "box")
    return VersionEntry(name, str(meta.get("version_id", "?")), parent, edit, prompt, current)


def store_entries(store: SceneStore) -> list[VersionEntry]:
    current, rows = store.current, []
    for name in store.names():
        info = store.info(name)
        parent = info.manifest.get("parent") or info.meta.get("parent") or "-"
        rows.append(_entry(name, info.meta, str(parent), name == current))
    return rows


def plain_entries(folders: dict[str, Path], shown: str) -> list[VersionEntry]:
    metas = {}
    for name, path in folders.items():
        try:
            metas[name] = json.loads((path / "scene.json").read_text())
        except (OSError, ValueError) as e:
            raise NeoError(f"{path}: cannot read scene.json: {e}") from None
    by_id = {str(m.get("version_id")): n for n, m in metas.items()}
    return [
        _entry(n, m, by_id.get(str(m.get("parent")), str(m.get("parent") or "-")), n == shown)
        for n, m in metas.items()
    ]


def versions_markdown(entries: list[VersionEntry], shown: str) -> str:
    """A markdown table of the versions (the current one marked, the one shown in bold)."""
    lines = ["| version | parent | edit | prompt |", "|---|---|---|---|"]
    for e in entries:
        name = e.name + (" (current)" if e.current else "")
        if e.name == shown:
            name = f"**{name}**"
        prompt = e.prompt.replace("|", "/")
        lines.append(f"| {name} | {e.parent} | {e.edit} | {prompt} |")
    return "\n".join(lines)


def new_version_path(store: SceneStore | None, parent_dir: Path, kind: str) -> Path:
    """Where a commit writes: ``STORE/<kind>_<k>`` or, beside a plain scene folder,
    ``<folder>_<kind>_<k>`` (the first k that is free)."""
    parent_dir = Path(parent_dir).resolve()  # "." has no name
    for k in range(1, 10_000):
        out = (
            store.root / f"{kind}_{k}"
            if store is not None
            else parent_dir.parent / f"{parent_dir.name}_{kind}_{k}"
        )
        if not out.exists():
            return out
    raise NeoError(f"no free name for a new {kind} version beside {parent_dir}")


def commit_edit(
    store: SceneStore | None,
    parent_dir: Path,
    parent: Scene,
    edit: PendingEdit,
    remove_cfg: RemoveConfig,
    move_cfg: MoveConfig,
    report: Report,
) -> tuple[str, Path, Scene]:
    """Run ``edit`` in full on ``parent`` and write the new version; (name, folder, scene)."""
    out = new_version_path(store, parent_dir, edit.kind)
    check_output(parent_dir, out)
    with edit_lock(out), progress_listener(report):
        if edit.kind == "remove":
            removal = Remove([edit.box], remove_cfg, edit.prompt)
            child, strips = apply_edit(parent, removal), removal.strips
        else:
            assert edit.transform is not None
            motion = Motion(edit.box, edit.transform)
            child, strips = apply_edit(parent, Move([motion], move_cfg, edit.prompt)), []
        report("writing the version", 1.0)
        save_scene(out, child, extras=lambda d: write_report(d / "report", parent, child, strips))
    return out.name, out, child
