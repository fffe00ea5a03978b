"""Safe writes: a reader never sees a half-written file or directory, a crash leaves nothing
that the next run does not clean up, and nothing but a neoedit output of the same kind is
ever replaced.

Temporaries live beside their output as ``.NAME.neoedit-PID-XXXXXXXX.{tmp,partial,old,trash}``;
a later write in the same folder removes those whose process is gone (a backup ``.old``
whose output is missing is put back instead). Files and folders are fsynced before the
rename that publishes them, and a previous version is swapped out in one atomic
``renameat2(RENAME_EXCHANGE)`` where the system has it. New files and folders get the
user's umask.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import re
import secrets
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np

from neoedit.errors import NeoError
from neoedit.utils.durable import exchange, fsync_dir, seal_tree
from neoedit.utils.written import LIST, record_files, refuse_foreign_files

TAG = "neoedit"
MARKER = ".neoedit-output.json"
"""Marks a folder as a neoedit output (renders, evaluation images, query pictures)."""
MARKER_FORMAT = "neoedit.output/1"
PROTECTED_JSON = {"transforms.json", "scene.json", "objects.json", "suite.json", MARKER, LIST}
PROTECTED_JSON |= {"store.json", "tensors.json"}
PROTECTED_JSON |= {f"transforms_{s}.json" for s in ("train", "val", "test")}
_TEMP_RE = re.compile(
    r"^\.(?P<name>.+)\.neoedit-(?P<pid>\d+)-[0-9a-f]{8}\.(?P<kind>tmp|partial|old|trash)$"
)
_LEGACY_RE = re.compile(r"^\.(?P<name>.+)\.[a-z0-9_]{8}\.(?P<kind>tmp|partial|old)$")
_ACTIVE: set[str] = set()
"""Temporaries this process is writing right now (never cleaned up as stale)."""


def _temp_path(final: Path, kind: str) -> Path:
    name = f".{final.name}.{TAG}-{os.getpid()}-{secrets.token_hex(4)}.{kind}"
    return final.parent / name


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return False  # our own: stale unless registered in _ACTIVE
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def clean_stale_temporaries(parent: Path, name: str | None = None) -> list[Path]:
    """Remove what crashed writers left in ``parent`` (of output ``name`` only, if given);
    a backup whose output is missing is restored instead. Returns the paths handled."""
    handled: list[Path] = []
    try:
        entries = sorted(Path(parent).iterdir())
    except OSError:
        return handled
    for entry in entries:
        m = _TEMP_RE.match(entry.name)
        legacy = m is None
        if m is None:
            m = _LEGACY_RE.match(entry.name)
            if m is None or m["name"] != name:
                continue  # an old-style temporary is only recognised by its output's name
        elif str(entry) in _ACTIVE or _pid_alive(int(m["pid"])):
            continue
        if name is not None and m["name"] != name:
            continue
        final = entry.parent / m["name"]
        source = entry / m["name"] if legacy and m["kind"] == "old" else entry
        if m["kind"] == "old" and not final.exists() and source.exists():
            os.replace(source, final)  # the crash came between the two renames: put it back
        _remove(entry)
        handled.append(entry)
    return handled


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via an fsynced temporary sibling and an atomic rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_path(path, "tmp")
    _ACTIVE.add(str(tmp))
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # umask applies
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        fsync_dir(path.parent)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    finally:
        _ACTIVE.discard(str(tmp))


def atomic_write_json(path: Path, obj: Any) -> None:
    atomic_write_bytes(Path(path), (json.dumps(obj, indent=2) + "\n").encode())


IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
"""Formats :func:`write_image` writes (by the file name's suffix)."""


def write_image(path: Path, image: np.ndarray) -> None:
    """Write a uint8 image in the format its name says (PNG, or JPEG at quality 95),
    atomically (parent folders are created)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in IMAGE_SUFFIXES:
        raise NeoError(f"{path}: cannot write a {suffix or 'suffix-less'} image (use .png or .jpg)")
    if suffix == ".png":
        write_png(path, image)
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, iio.imwrite("<bytes>", image, extension=".jpg", quality=95))


def write_png(path: Path, image: np.ndarray) -> None:
    """Write a uint8 or uint16 image as PNG, atomically (parent folders are created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, iio.imwrite("<bytes>", image, extension=".png"))


def _discard(path: Path, final: Path) -> None:
    """Delete a previous version: first renamed to a ``.trash`` name (never restored), so an
    interrupted deletion cannot leave a half-deleted backup that looks restorable."""
    trash = _temp_path(final, "trash")
    os.replace(path, trash)
    _remove(trash)


def _publish(tmp: Path, final: Path) -> None:
    """Make the complete, fsynced ``tmp`` the new ``final``; at every moment ``final`` is
    either the previous version or the new one (or, without ``renameat2``, the previous
    version sits under an ``.old`` name that the next run restores)."""
    seal_tree(tmp)
    if not (final.exists() or final.is_symlink()):
        os.replace(tmp, final)
    elif exchange(tmp, final):
        fsync_dir(final.parent)
        _discard(tmp, final)  # tmp now holds the previous version
    else:
        backup = _temp_path(final, "old")
        _ACTIVE.add(str(backup))
        try:
            os.replace(final, backup)
            os.replace(tmp, final)
            fsync_dir(final.parent)
            _discard(backup, final)
        finally:
            _ACTIVE.discard(str(backup))
    fsync_dir(final.parent)


def _make_temp_dir(final: Path) -> Path:
    tmp = _temp_path(final, "partial")
    _ACTIVE.add(str(tmp))
    tmp.mkdir(mode=0o777)  # the umask applies
    return tmp


@contextlib.contextmanager
def work_directory(final: Path) -> Iterator[Path]:
    """A scratch folder beside ``final`` for the work that makes it, removed at the end; one a
    killed process leaves is removed by the next write in that folder (its name holds the
    pid, as the temporaries of :func:`atomic_directory` do)."""
    final = Path(final).absolute()
    final.parent.mkdir(parents=True, exist_ok=True)
    work = _temp_path(final, "tmp")
    _ACTIVE.add(str(work))
    try:
        work.mkdir(mode=0o700)
        yield work
    finally:
        _remove(work)
        _ACTIVE.discard(str(work))


@contextlib.contextmanager
def atomic_directory(
    final: Path, overwrite: bool = False, kind: str | None = None
) -> Iterator[Path]:
    """Yield a temporary directory that becomes ``final`` only if the block succeeds.

    On an exception the temporary directory is removed; after a hard kill the next write in
    the same folder removes it. An existing ``final`` is replaced only with ``overwrite`` and
    only if it is a neoedit output (of ``kind``, when given) or an empty folder. Folders of
    kinds other than scenes and simulated scans are marked with :data:`MARKER`.
    """
    final = Path(final)
    if final.exists() or final.is_symlink():
        if not overwrite and not _is_empty_dir(final):
            raise NeoError(
                f"output directory already exists: {final} (pass --overwrite to replace it)"
            )
        refuse_foreign(final, kind)
        refuse_foreign_files(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    clean_stale_temporaries(final.parent, final.name)
    tmp = _make_temp_dir(final)
    try:
        yield tmp
        if kind is not None and kind not in ("scene", "sim"):
            mark_output(tmp, kind)
        record_files(tmp)
        _publish(tmp, final)
    except BaseException:
        _remove(tmp)
        raise
    finally:
        _ACTIVE.discard(str(tmp))


# -- what an existing path is, and whether a command may write there --------------------------


def _read_json_quiet(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def mark_output(folder: Path, kind: str) -> None:
    atomic_write_json(Path(folder) / MARKER, {"format": MARKER_FORMAT, "kind": kind})


def output_kind(path: Path) -> str | None:
    """'scene' (neoedit scene), 'store' (a scene store: ``neo plan --out``), 'sim' (simulated
    scans), the kind in a :data:`MARKER`, or None when ``path`` is not a neoedit output folder."""
    path = Path(path)
    if not path.is_dir():
        return None
    store = _read_json_quiet(path / "store.json") if (path / "store.json").is_file() else None
    if isinstance(store, dict) and str(store.get("format", "")).startswith("neoedit.store/"):
        return "store"
    meta = _read_json_quiet(path / "scene.json") if (path / "scene.json").is_file() else None
    if isinstance(meta, dict):
        if meta.get("format") == "neoedit.scene/1":
            return "scene"
        if {"scans", "spec", "actions"} <= meta.keys():
            return "sim"
    marker = _read_json_quiet(path / MARKER) if (path / MARKER).is_file() else None
    if isinstance(marker, dict) and marker.get("format") == MARKER_FORMAT:
        kind = marker.get("kind")
        return kind if isinstance(kind, str) else None
    with contextlib.suppress(OSError):  # a query folder written before the marker existed
        if [p.name for p in path.iterdir()] == ["query.png"]:
            return "query"
    return None


def _is_empty_dir(path: Path) -> bool:
    try:
        return path.is_dir() and not path.is_symlink() and not any(path.iterdir())
    except OSError:
        return False


def _replaceable_json(path: Path) -> bool:
    """A --json output may replace a previous result: a JSON file that is no dataset or
    scene metadata."""
    return (
        path.is_file()
        and not path.is_symlink()
        and path.name not in PROTECTED_JSON
        and _read_json_quiet(path) is not None
    )


def refuse_foreign(path: Path, kind: str | None, option: str = "--out") -> None:
    """Raise unless the existing ``path`` may be replaced by an output of ``kind``
    (``option``: the command's option that named it, for the message)."""
    if kind == "json":
        if not _replaceable_json(path):
            raise NeoError(
                f"{path} exists and is not a previous JSON result; refusing to replace it "
                "(choose another path)"
            )
        return
    found = output_kind(path)
    if _is_empty_dir(path) or (found is not None and (kind is None or found == kind)):
        return
    what = (
        "a file"
        if path.is_file()
        else "not a neoedit output"
        if found is None
        else "a scene store"
        if found == "store"
        else f"a neoedit {found}"
    )
    raise NeoError(
        f"{path} exists and is {what}; refusing to replace it with a neoedit "
        f"{kind or 'output'} (choose another {option})"
    )


def _nearest_existing(path: Path) -> Path:
    for candidate in [path, *path.parents]:
        if candidate.exists():
            return candidate
    return Path.cwd()


def probe_writable(folder: Path) -> None:
    """Create and remove a file in ``folder``; a clear NeoError if that is not possible."""
    try:
        fd, probe = tempfile.mkstemp(prefix=f".{TAG}-probe-", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise NeoError(f"cannot write to {folder}: {e.strerror or e}") from None


def _holder(folder: Path) -> str | None:
    """'a scene' / 'a scene store' when ``folder`` is one, else None."""
    if (folder / "store.json").is_file():
        return "a scene store"
    return "a scene" if output_kind(folder) == "scene" else None


def _check_not_inside_scene(out: Path) -> None:
    """Outputs never go into a scene, a store or a store's version (their files are the
    scene's own; a stray file there is lost or confuses the next load)."""
    for parent in out.resolve().parents:
        what = _holder(parent)
        if what is not None:
            raise NeoError(f"{out} is inside {what} ({parent}); write outputs elsewhere")


def _check_not_input(out: Path, inputs: Sequence[Path | None]) -> None:
    out_r = out.resolve()
    for inp in inputs:
        if inp is None:
            continue
        inp_r = Path(inp).resolve()
        if out_r == inp_r:
            raise NeoError(
                f"{out} is an input of this command; an output never overwrites its input"
            )
        if inp_r in out_r.parents:
            raise NeoError(f"{out} is inside the input {inp}; an output never goes into an input")
        if out_r in inp_r.parents and out.exists():
            raise NeoError(f"{out} holds the input {inp}; replacing it would delete the input")


def _check_replaceable(out: Path, option: str = "--out") -> None:
    """An existing output folder is replaced by a rename: a mount point cannot be, and a
    folder that refuses new files (read-only, immutable) is found here, not after the work."""
    if out.is_dir() and not out.is_symlink():
        if os.path.ismount(out):
            raise NeoError(
                f"{out} is a mount point, which cannot be replaced; write into a new folder "
                f"inside it (e.g. {option} {out / 'result'})"
            )
        probe_writable(out)


def check_writable_output(
    out: Path,
    inputs: Sequence[Path | None] = (),
    kind: str = "scene",
    overwrite: bool = False,
    hint: str = "pass --overwrite to replace it",
    option: str = "--out",
) -> None:
    """Everything a writing command checks before its work starts (one rule for every verb).

    ``out`` must not be, be inside or hold one of ``inputs``; an existing ``out`` must be a
    neoedit output of ``kind`` (or an empty folder; for kind 'json', a JSON file that is no
    dataset or scene metadata) and is replaced only with ``overwrite`` (``hint`` says
    how to ask for that; ``option``, the option that named ``out``, for messages); ``out``
    must not lie inside a scene or a store; the folder it goes to must be writable. Also
    removes what crashed runs left there.
    """
    out = Path(out)
    _check_not_input(out, inputs)
    _check_not_inside_scene(out)
    if out.exists() or out.is_symlink():
        refuse_foreign(out, kind, option)
        if not overwrite and not _is_empty_dir(out):
            raise NeoError(f"{out} already exists ({hint})")
        _check_replaceable(out, option)
        if out.is_dir():
            refuse_foreign_files(out)
    anchor = _nearest_existing(out.parent)
    if not anchor.is_dir():
        raise NeoError(f"cannot write {out}: {anchor} is not a directory")
    probe_writable(anchor)
    if anchor == out.parent:
        clean_stale_temporaries(anchor)
    lock_output(out)


_HELD_LOCKS: dict[str, int] = {}
"""Outputs this process holds the writer lock of (file descriptors, kept open until exit)."""


def lock_output(out: Path) -> None:
    """Hold, for the rest of this process, the lock on writing ``out``: a second neo process
    that is to write the same output fails at its checks, before its work, instead of
    silently replacing the first one's result. The locks live in the temporary folder (one
    per user), not beside the user's files; the system releases them when a process ends,
    killed or not. Best effort: where no lock file can be made, nothing is locked."""
    key = hashlib.sha256(str(Path(out).resolve()).encode()).hexdigest()[:24]
    if key in _HELD_LOCKS:
        return
    try:
        folder = Path(tempfile.gettempdir()) / f"neoedit-locks-{os.getuid()}"
        folder.mkdir(mode=0o700, exist_ok=True)
        fd = os.open(folder / f"{key}.lock", os.O_RDWR | os.O_CREAT, 0o600)
    except OSError:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise NeoError(
            f"{out} is being written by another neo process; wait for it to finish or choose "
            "another output"
        ) from None
    _HELD_LOCKS[key] = fd


def default_output(kind: str, scene: Path, request: str) -> Path:
    """A new folder ``outputs/<kind>/<scene name>-<request>`` (the request made file-name
    safe, e.g. the prompt), numbered ``-2``, ``-3`` ... when that name is taken, so that two
    calls with default outputs never collide nor replace each other's results."""
    slug = re.sub(r"[^A-Za-z0-9]+", "-", request).strip("-").lower()[:40] or "result"
    base = Path("outputs") / kind / f"{Path(scene).resolve().name}-{slug}"
    candidate, n = base, 1
    while candidate.exists() or candidate.is_symlink():
        n += 1
        candidate = base.with_name(f"{base.name}-{n}")
    return candidate
