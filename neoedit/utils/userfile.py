"""Reading the small text files a user hands a command (plans, scene specs, boxes,
transforms, grasps): a regular file of bounded size, UTF-8, parsed as JSON or YAML, with
one clear error for each way it can fail (``/dev/zero`` or a 10 GB log is refused before
it is read, not after the memory is gone)."""

from __future__ import annotations

import json
import stat
from pathlib import Path
from typing import Any

import yaml

from neoedit.errors import NeoError

MAX_BYTES = 16 << 20
"""Largest option file read (16 MiB: a plan or a box list is a few kilobytes)."""


def read_text_file(path: Path, what: str, max_bytes: int = MAX_BYTES) -> str:
    """The text of ``path`` ('what' names it in messages: 'plan', 'scene spec', ...)."""
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        raise NeoError(f"{what} not found: {path}") from None
    except OSError as e:
        raise NeoError(f"{path}: cannot read the {what}: {e.strerror or e}") from None
    if not stat.S_ISREG(info.st_mode):
        kind = "a folder" if stat.S_ISDIR(info.st_mode) else "not a regular file"
        raise NeoError(f"{path}: the {what} must be a file ({kind})")
    if info.st_size > max_bytes:
        raise NeoError(
            f"{path}: {info.st_size / 2**20:.0f} MiB is too large for a {what} "
            f"(at most {max_bytes >> 20} MiB)"
        )
    try:
        with path.open("rb") as f:
            data = f.read(max_bytes + 1)
    except OSError as e:
        raise NeoError(f"{path}: cannot read the {what}: {e.strerror or e}") from None
    if len(data) > max_bytes:
        raise NeoError(f"{path}: too large for a {what} (at most {max_bytes >> 20} MiB)")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise NeoError(f"{path}: the {what} is not UTF-8 text") from None


def read_data_file(path: Path, what: str, yaml_ok: bool = False) -> Any:
    """The parsed content of a JSON file (or YAML, when ``yaml_ok`` and the name does not end
    in .json)."""
    path = Path(path)
    text = read_text_file(path, what)
    as_yaml = yaml_ok and path.suffix.lower() != ".json"
    try:
        if as_yaml:
            return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 (a SafeLoader)
        return json.loads(text, object_pairs_hook=_unique_keys)
    except (ValueError, yaml.YAMLError, RecursionError) as e:
        raise NeoError(
            f"{path}: the {what} is not valid {'YAML' if as_yaml else 'JSON'}: {_one_line(e)}"
        ) from None


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object whose keys are all different (a key given twice would silently keep
    only its last value)."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"the key {key!r} is given twice in one object")
        out[key] = value
    return out


class _UniqueKeyLoader(yaml.SafeLoader):
    """YAML's safe loader, refusing a mapping that gives one key twice."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if not isinstance(key, (str, int, float, bool)):
                continue
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None,
                    None,
                    f"the key {key!r} is given twice in one mapping",
                    key_node.start_mark,
                )
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def _one_line(error: BaseException) -> str:
    """A parser's complaint in one line: YAML's multi-line report (context, caret drawings)
    becomes its problem and where it is ('line 3, column 4: expected <block end>, ...')."""
    mark = getattr(error, "problem_mark", None)
    problem = getattr(error, "problem", None)
    if mark is not None and problem:
        return f"line {mark.line + 1}, column {mark.column + 1}: {problem}"
    return " ".join(str(error).split())
