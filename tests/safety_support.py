"""Helpers of the data-safety tests (issue 12): run ``neo`` the way a user does and check
that a refused command left the workspace exactly as it was."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from neoedit.cli import main
from tests.conftest import tiny_train

# the tiny field of the tests, as command-line options (a train run takes about a second)
TINY_TRAIN_ARGS = [
    "--max-steps", "2",
    "--rays-per-batch", "64",
    "--eval-every", "0",
    "--eval-views", "1",
    "--checkpoint-every", "0",
    "--skip-language",
    "--field.hidden-dim", "8",
    "--field.hidden-dim-color", "8",
    "--field.hashgrid.n-levels", "2",
    "--field.hashgrid.log2-hashmap-size", "8",
    "--grid.resolution", "8",
    "--render.n-march-samples", "16",
    "--render.n-coarse-samples", "8",
    "--render.n-samples", "4",
    "--device", "cpu",
]  # fmt: skip


@pytest.fixture(scope="session")
def golden(sim_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The tiny removal_1 pre scan and a scene trained on it for 10 steps (tests copy both
    with :func:`make_workspace` before touching them)."""
    data = sim_root / "removal_1" / "pre"
    scene = tmp_path_factory.mktemp("golden") / "scene"
    tiny_train(data, scene, steps=10)
    return data, scene


@dataclass
class Outcome:
    code: int | None
    err: str
    out: str
    traceback: str | None = None
    """An exception that escaped ``main`` (never acceptable)."""


def run_neo(argv: list[str], capsys: Any) -> Outcome:
    """``neo ARGV`` in this process: exit status, stderr, stdout and any escaped traceback."""
    capsys.readouterr()
    tb = None
    try:
        code: int | None = main([str(a) for a in argv])
    except SystemExit as e:  # argument parsing (tyro) exits by itself
        code = int(e.code or 0) if not isinstance(e.code, str) else 2
    except BaseException:  # noqa: BLE001 -- the test reports it
        code, tb = None, traceback.format_exc()
    captured = capsys.readouterr()
    return Outcome(code, " ".join(captured.err.split()), captured.out, tb)


def snapshot(root: Path) -> dict[str, str]:
    """Every path under ``root`` with its content hash (folders: 'dir') and mode."""
    state = {}
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root).as_posix()
        if p.is_symlink():
            state[rel] = "link"
        elif p.is_dir():
            state[rel] = f"dir {p.stat().st_mode & 0o777:o}"
        else:
            state[rel] = hashlib.sha1(p.read_bytes()).hexdigest()
    return state


def changes(before: dict[str, str], after: dict[str, str]) -> list[str]:
    return sorted({k for k in before.keys() | after.keys() if before.get(k) != after.get(k)})


def temporaries(folder: Path) -> list[str]:
    """neoedit temporaries (and probes) anywhere under ``folder``."""
    pattern = re.compile(
        r"(\.neoedit-\d+-[0-9a-f]{8}\.(tmp|partial|old|trash)|^\.neoedit-probe-.*)$"
    )
    return sorted(p.name for p in folder.rglob(".*") if pattern.search(p.name))


@dataclass
class Workspace:
    """A fresh folder holding a copy of the tiny dataset (``data``) and scene (``scene``)."""

    root: Path
    data: Path = field(init=False)
    scene: Path = field(init=False)

    def __post_init__(self) -> None:
        self.data = self.root / "data"
        self.scene = self.root / "scene"

    def path(self, name: str) -> Path:
        return self.root / name

    def transforms(self) -> dict[str, Any]:
        return json.loads((self.data / "transforms.json").read_text())

    def write_transforms(self, meta: Any, text: str | None = None) -> None:
        (self.data / "transforms.json").write_text(text if text is not None else json.dumps(meta))

    def scene_json(self) -> dict[str, Any]:
        return json.loads((self.scene / "scene.json").read_text())

    def write_scene_json(self, meta: Any) -> None:
        (self.scene / "scene.json").write_text(json.dumps(meta))

    def write(self, name: str, content: Any) -> Path:
        path = self.root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        elif isinstance(content, str):
            path.write_text(content)
        elif isinstance(content, np.ndarray):
            np.save(path, content)
        else:
            path.write_text(json.dumps(content))
        return path


def make_workspace(tmp: Path, data: Path, scene: Path) -> Workspace:
    ws = Workspace(tmp)
    shutil.copytree(data, ws.data)
    shutil.copytree(scene, ws.scene)
    meta = ws.scene_json()
    meta["data_path"] = str(ws.data.resolve())  # the copy, so nothing outside tmp is read
    ws.write_scene_json(meta)
    return ws


Setup = Callable[[Workspace], None]


def set_frame(index: int | None = None, **values: Any) -> Setup:
    """Set keys of one frame (or, with ``index`` None, the global keys) of transforms.json."""

    def apply(ws: Workspace) -> None:
        meta = ws.transforms()
        target = meta if index is None else meta["frames"][index]
        target.update(values)
        ws.write_transforms(meta)

    return apply


def scale_rotation(factor: float) -> Setup:
    def apply(ws: Workspace) -> None:
        meta = ws.transforms()
        m = np.asarray(meta["frames"][0]["transform_matrix"], dtype=float)
        m[:3, :3] *= factor
        meta["frames"][0]["transform_matrix"] = m.tolist()
        ws.write_transforms(meta)

    return apply


def set_scene(**values: Any) -> Setup:
    def apply(ws: Workspace) -> None:
        meta = ws.scene_json()
        meta.update(values)
        ws.write_scene_json(meta)

    return apply


def nan_weights(ws: Workspace) -> None:
    from safetensors.torch import load_file, save_file

    path = ws.scene / "field.safetensors"
    tensors = load_file(str(path))
    key = next(k for k in tensors if "mlp" in k and k.endswith("weight"))
    tensors[key][0, 0] = float("nan")
    save_file(tensors, str(path))


def pickled_depth(ws: Workspace) -> None:
    np.save(ws.data / "depth" / "evil.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    set_frame(0, depth_file_path="depth/evil.npy")(ws)


def chain(*steps: Setup) -> Setup:
    def apply(ws: Workspace) -> None:
        for step in steps:
            step(ws)

    return apply
