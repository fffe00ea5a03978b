"""Scene versions: every edit writes a new version directory and never touches its parent."""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import time
import uuid
from pathlib import Path

from neoedit.errors import NeoError
from neoedit.records import EditRecord
from neoedit.scene import Scene
from neoedit.storage import find_store, resolve_scene_dir
from neoedit.storage.store import NAME_RE
from neoedit.utils.io import check_writable_output


def check_output(parent_dir: Path, out: Path, overwrite: bool = False) -> None:
    """Refuse to write an edit over its input version, or over any scene without --overwrite;
    in a scene store, over any version at all (a store's versions are never replaced)."""
    parent_dir = resolve_scene_dir(parent_dir)
    store = find_store(out)
    if store is not None:
        if Path(out).exists():
            raise NeoError(
                f"{out} already exists: versions in a scene store are never replaced "
                "(choose another name)"
            )
        if not NAME_RE.match(Path(out).name):
            raise NeoError(
                f"{Path(out).name!r} is not a valid version name (letters, digits, _ . -)"
            )
        return
    if Path(out).resolve() == Path(parent_dir).resolve():
        raise NeoError(
            f"--out {out} is the input scene: an edit never overwrites the version it started from"
        )
    hint = "choose another --out or pass --overwrite"
    check_writable_output(out, [parent_dir], "scene", overwrite, hint)  # only a scene is replaced


def edit_lock(out: Path) -> contextlib.AbstractContextManager[None]:
    """The writer lock of the store ``out`` goes into (held from the first check to the
    save, so a second writer fails at once); nothing for a plain scene folder."""
    store = find_store(out)
    return store.lock() if store is not None else contextlib.nullcontext()


def new_version(parent: Scene, record: EditRecord) -> Scene:
    """A deep copy of ``parent`` as a new version: fresh id, parent link, the edit appended
    to the history. The parent object is left unchanged."""
    child = Scene(
        copy.deepcopy(parent.field),
        copy.deepcopy(parent.grid),
        copy.deepcopy(parent.meta),
        copy.deepcopy(parent.language),
        None if parent.surface_points_m is None else parent.surface_points_m.clone(),
    )
    meta = child.meta
    meta.parent = parent.meta.version_id
    meta.version_id = uuid.uuid4().hex[:12]
    meta.created = time.strftime("%Y-%m-%dT%H:%M:%S")
    meta.edits.append(
        dataclasses.replace(record, parent=parent.meta.version_id, version=meta.version_id)
    )
    return child
