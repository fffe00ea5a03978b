"""A scene store: every version of one scene, written once, sharing what they have in common.

Layout::

    STORE/
      store.json          {"format": "neoedit.store/1", "current": NAME}
      blobs/              content-addressed tensor blobs (:mod:`neoedit.storage.blobs`)
      NAME/               one version: scene.json, tensors.json (which blob holds each
                          tensor, in full or as a delta against the parent version), report/
      .lock               held (flock) by the one process writing the store

A version directory is a scene every verb accepts; ``STORE`` itself stands for its current
version. A version is published atomically (blobs first, then its directory, then the
current pointer), so a writer killed at any point leaves every earlier version readable.
``restore`` moves the current pointer only: no version is ever rewritten or deleted.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import re
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from neoedit.errors import NeoError
from neoedit.storage.blobs import decode, encode, get_blob, put_blob
from neoedit.utils.io import atomic_directory, atomic_write_json, clean_stale_temporaries

FORMAT = "neoedit.store/1"
MANIFEST = "tensors.json"
MANIFEST_FORMAT = "neoedit.tensors/1"
_HELD: dict[str, int] = {}
"""Store roots whose writer lock this process holds (an flock is per open file, so a second
open in the same process must not try again)."""
_LAST: dict[str, tuple[tuple[str, str], Groups]] = {}
"""Per store root, the last version this process rebuilt or wrote (the next edit's parent)."""
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")
Groups = dict[str, dict[str, torch.Tensor]]
"""Tensor groups of a version: 'field' (radiance field, patches, grid), 'language'."""


def is_store(path: Path) -> bool:
    return (Path(path) / "store.json").is_file()


def find_store(version_dir: Path) -> SceneStore | None:
    """The store a version directory belongs to (its parent folder), or None."""
    parent = Path(version_dir).absolute().parent
    return SceneStore(parent) if is_store(parent) else None


def resolve_scene_dir(path: Path) -> Path:
    """The version directory a scene argument names: a store's current version, or the path."""
    path = Path(path)
    return SceneStore(path).current_dir() if is_store(path) else path


@dataclass
class VersionInfo:
    name: str
    meta: dict[str, Any]
    manifest: dict[str, Any]


class SceneStore:
    """The versions of a scene in one folder (see the module docstring for the layout)."""

    def __init__(self, root: Path):
        self.root = Path(root)

    # -- creation and the current pointer ---------------------------------------------------
    @classmethod
    def create(cls, root: Path) -> SceneStore:
        root = Path(root)
        if is_store(root):
            return cls(root)
        if root.exists() and (not root.is_dir() or any(root.iterdir())):
            raise NeoError(f"{root} exists and is not a scene store (choose another folder)")
        (root / "blobs").mkdir(parents=True, exist_ok=True)
        atomic_write_json(root / "store.json", {"format": FORMAT, "current": None})
        return cls(root)

    def _config(self) -> dict[str, Any]:
        try:
            raw = json.loads((self.root / "store.json").read_text())
        except (OSError, ValueError) as e:
            raise NeoError(f"{self.root}/store.json: cannot read the store: {e}") from None
        if not isinstance(raw, dict) or raw.get("format") != FORMAT:
            raise NeoError(f"{self.root}/store.json: not a {FORMAT} store")
        return raw

    @property
    def current(self) -> str | None:
        return self._config().get("current")

    def current_dir(self) -> Path:
        name = self.current
        if name is None:
            raise NeoError(f"scene store {self.root} holds no version yet")
        self.info(name)  # a valid name of a version of this store
        return self.root / name

    def names(self) -> list[str]:
        """Version names, oldest first: in the order they were written (each manifest holds
        its number, so a copied store whose files got new times keeps its order; versions of
        stores written before numbering come first, by modification time)."""
        found = []
        for d in self.root.iterdir():  # a writer's temporary folder (".NAME.neoedit-...") is none
            if not NAME_RE.match(d.name) or d.name == "blobs":
                continue
            if d.is_dir() and (d / MANIFEST).is_file() and (d / "scene.json").is_file():
                found.append((_number(d / MANIFEST), d.stat().st_mtime_ns, d.name))
        return [n for *_, n in sorted(found)]

    def info(self, name: str) -> VersionInfo:
        if not isinstance(name, str) or not NAME_RE.match(name) or name == "blobs":
            raise NeoError(f"{self.root}: {name!r} is not a version name of this store")
        d = self.root / name
        try:
            meta = json.loads((d / "scene.json").read_text())
            manifest = json.loads((d / MANIFEST).read_text())
        except FileNotFoundError:
            raise NeoError(
                f"no version {name!r} in {self.root} (versions: {', '.join(self.names())})"
            ) from None
        except (OSError, ValueError) as e:
            raise NeoError(f"{d}: cannot read the version: {e}") from None
        if manifest.get("format") != MANIFEST_FORMAT:
            raise NeoError(f"{d / MANIFEST}: not a {MANIFEST_FORMAT} manifest")
        return VersionInfo(name, meta, manifest)

    def find(self, key: str) -> str:
        """A version's name from its name or (a prefix of) its version id."""
        names = self.names()
        if key in names:
            return key
        hits = [n for n in names if str(self.info(n).meta.get("version_id", "")).startswith(key)]
        if len(hits) == 1:
            return hits[0]
        raise NeoError(
            f"no version {key!r} in {self.root}"
            + (" (ambiguous id)" if hits else "")
            + f"; versions: {', '.join(names) or 'none'}"
        )

    def name_of_id(self, version_id: str | None) -> str | None:
        if version_id is None:
            return None
        for n in self.names():
            if self.info(n).meta.get("version_id") == version_id:
                return n
        return None

    # -- the writer lock ----------------------------------------------------------------------
    @contextlib.contextmanager
    def lock(self) -> Iterator[None]:
        """Hold the store's writer lock (re-entrant in one process); a second writer gets a
        clear error at once instead of waiting or corrupting the store."""
        key = str(self.root.resolve())
        if key in _HELD:
            yield
            return
        path = self.root / ".lock"
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise NeoError(
                f"scene store {self.root} is being written by another neo process ({holder}); "
                "wait for it to finish"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} since {time.strftime('%H:%M:%S')}".encode(), 0)
        _HELD[key] = fd
        try:
            yield
        finally:
            del _HELD[key]
            os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)

    def set_current(self, name: str) -> None:
        with self.lock():
            self.info(name)  # it must exist
            atomic_write_json(self.root / "store.json", {**self._config(), "current": name})

    # -- reading and writing versions -------------------------------------------------------
    def tensors(self, name: str) -> Groups:
        """Every tensor group of a version, rebuilt through its parents' deltas."""
        cache_key = (name, json.dumps(self.info(name).manifest["groups"], sort_keys=True))
        last = _LAST.get(str(self.root.resolve()))
        if last is not None and last[0] == cache_key:
            return last[1]
        chain: list[VersionInfo] = []
        seen: set[str] = set()
        key: str | None = name
        while key is not None:
            if key in seen:
                raise NeoError(f"{self.root}: versions {sorted(seen)} form a parent cycle")
            seen.add(key)
            info = self.info(key)
            chain.append(info)
            needs_parent = any(
                e.get("enc") != "full"
                for g in info.manifest["groups"].values()
                for e in g["tensors"].values()
            )
            key = info.manifest.get("parent") if needs_parent else None
        groups: Groups | None = None
        for info in reversed(chain):
            built: Groups = {}
            for gname, g in info.manifest["groups"].items():
                payload = get_blob(self.root / "blobs", g["blob"])
                parent = None if groups is None else groups.get(gname)
                where = f"{self.root / info.name}"
                built[gname] = decode(payload, g["tensors"], parent, where)
            groups = built
        assert groups is not None  # the chain holds at least the version itself
        _LAST[str(self.root.resolve())] = (cache_key, groups)
        return groups

    def write(
        self,
        name: str,
        groups: Groups,
        meta: dict[str, Any],
        extras: Callable[[Path], None] | None = None,
        make_current: bool = True,
    ) -> Groups:
        """Publish a new version ``name`` (deltas against the parent version named by
        ``meta['parent']`` when it is in this store); returns the tensors as stored."""
        if not NAME_RE.match(name) or name in ("blobs", "store.json"):
            raise NeoError(f"{name!r} is not a valid version name (letters, digits, _ . -)")
        with self.lock():
            if (self.root / name).exists():
                raise NeoError(f"{self.root / name} already exists: versions are never replaced")
            self.collect_garbage()
            parent_name = self.name_of_id(meta.get("parent"))
            parent = self.tensors(parent_name) if parent_name is not None else None
            manifest: dict[str, Any] = {
                "format": MANIFEST_FORMAT,
                "parent": parent_name,
                "number": len(self.names()),
            }
            manifest["groups"], stored, size = {}, {}, 0
            for gname, tensors in groups.items():
                payload, entries, stored[gname] = encode(
                    tensors, None if parent is None else parent.get(gname)
                )
                digest, nbytes = put_blob(self.root / "blobs", payload)
                manifest["groups"][gname] = {"blob": digest, "bytes": nbytes, "tensors": entries}
                size += nbytes
            manifest["bytes"] = size
            with atomic_directory(self.root / name, kind="scene") as tmp:
                atomic_write_json(tmp / MANIFEST, manifest)
                atomic_write_json(tmp / "scene.json", meta)
                if extras is not None:
                    extras(tmp)
            cache_key = (name, json.dumps(manifest["groups"], sort_keys=True))
            _LAST[str(self.root.resolve())] = (cache_key, stored)
            if make_current:
                atomic_write_json(self.root / "store.json", {**self._config(), "current": name})
        return stored

    def collect_garbage(self) -> list[Path]:
        """Remove what killed writers left (their temporary version folders and blob
        temporaries, and blobs no version references); under the writer lock, so no write is
        in progress. Nothing is removed when a version's manifest cannot be read. Returns
        the paths removed."""
        with self.lock():
            removed = clean_stale_temporaries(self.root)
            blobs = self.root / "blobs"
            removed += clean_stale_temporaries(blobs)
            referenced = set()
            for d in self.root.iterdir():
                if not NAME_RE.match(d.name) or d.name == "blobs" or not d.is_dir():
                    continue
                try:
                    manifest = json.loads((d / MANIFEST).read_text())
                    referenced |= {g["blob"] for g in manifest["groups"].values()}
                except FileNotFoundError:
                    continue  # not a version (a user's folder)
                except (OSError, ValueError, KeyError, TypeError, AttributeError):
                    return removed  # a version that cannot be read: keep every blob
            for blob in blobs.glob("*.st.z") if blobs.is_dir() else ():
                if blob.name.removesuffix(".st.z") not in referenced:
                    blob.unlink(missing_ok=True)
                    removed.append(blob)
            return removed

    def size_bytes(self) -> int:
        """Bytes on disk of the whole store (blobs, manifests, metadata, reports)."""
        return sum(p.stat().st_size for p in self.root.rglob("*") if p.is_file())


def _number(manifest: Path) -> int:
    """A version's number in its store's write order (-1: written before numbering, or a
    manifest that cannot be read, which :meth:`SceneStore.info` reports)."""
    try:
        number = json.loads(manifest.read_text()).get("number", -1)
    except (OSError, ValueError, AttributeError):
        return -1
    return number if isinstance(number, int) else -1
