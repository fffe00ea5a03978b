"""What neoedit wrote in an output folder, so that ``--overwrite`` never deletes what a
user put there: every folder :func:`neoedit.utils.io.atomic_directory` publishes lists its
files in :data:`LIST`; replacing the folder is refused while it holds files not on the list
(a folder written before the list existed is replaced as before)."""

from __future__ import annotations

import json
import os
from pathlib import Path

from neoedit.errors import NeoError

LIST = ".neoedit-files.json"
FORMAT = "neoedit.files/1"
SHOWN = 5


def _files(folder: Path) -> list[str]:
    found = []
    for root, dirs, names in os.walk(folder):
        dirs.sort()
        for name in sorted(names):
            rel = Path(root, name).relative_to(folder).as_posix()
            if rel != LIST:
                found.append(rel)
    return found


def record_files(folder: Path) -> None:
    """Write the list of ``folder``'s files (called on the complete temporary folder)."""
    data = {"format": FORMAT, "files": _files(Path(folder))}
    (Path(folder) / LIST).write_text(json.dumps(data, indent=0) + "\n")


def foreign_files(folder: Path) -> list[str]:
    """Files in an existing output ``folder`` that neoedit did not write there (empty when
    the folder has no list: written before lists existed, or not a folder)."""
    folder = Path(folder)
    try:
        data = json.loads((folder / LIST).read_text())
        listed = set(data["files"]) if data.get("format") == FORMAT else None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return []
    if listed is None:
        return []
    return [f for f in _files(folder) if f not in listed and not _temporary(f)]


def _temporary(rel: str) -> bool:
    return ".neoedit-" in Path(rel).name  # a writer's temporary or probe, cleaned elsewhere


def refuse_foreign_files(folder: Path) -> None:
    """Raise before an output folder holding a user's files is replaced."""
    extra = foreign_files(folder)
    if extra:
        more = f" and {len(extra) - SHOWN} more" if len(extra) > SHOWN else ""
        raise NeoError(
            f"{folder} holds files neoedit did not write ({', '.join(extra[:SHOWN])}{more}); "
            "--overwrite would delete them: move them out or choose another --out"
        )
