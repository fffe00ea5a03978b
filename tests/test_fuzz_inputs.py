"""Property tests of issue 12: a valid tiny transforms.json or scene.json, changed at random
places to random values, gives exactly two outcomes: success, or one clear NeoError
message with exit status 2 and nothing written. Never a traceback, never a partial output.
"""

# ruff: noqa: F811 (the golden fixture is imported and used as an argument)
from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from neoedit.scene import load_scene
from tests.safety_support import (
    TINY_TRAIN_ARGS,
    changes,
    golden,  # noqa: F401 (a fixture)
    make_workspace,
    run_neo,
    snapshot,
    temporaries,
)

NASTY = st.one_of(
    st.sampled_from(
        [
            None,
            True,
            False,
            0,
            -1,
            1,
            2,
            3,
            0.5,
            -0.0,
            1e308,
            -1e308,
            1e-300,
            math.nan,
            math.inf,
            -math.inf,
            "",
            "x",
            "0",
            "../../x",
            "/etc/passwd",
            [],
            {},
            [0, 0, 0],
            [[0, 0, 0], [0, 0, 0]],
            [1, 2],
            {"a": 1},
        ]
    ),  # fmt: skip
    st.integers(-(10**6), 10**6),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=5),
)


def paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    """Every place in a JSON document (the root excluded)."""
    found = []
    items = (
        doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else []
    )
    for key, value in items:
        found.append((*prefix, key))
        found += paths(value, (*prefix, key))
    return found


def mutate(doc: Any, data: st.DataObject, n_max: int = 3) -> Any:
    """1..n_max random changes: replace a value, delete a key or an item, or drop a list's tail."""
    for _ in range(data.draw(st.integers(1, n_max), label="changes")):
        places = paths(doc)
        if not places:
            break
        shallow = [p for p in places if len(p) <= 3]  # keys of the file and of each frame
        pool = data.draw(st.sampled_from([shallow, shallow, places])) if shallow else places
        where = data.draw(st.sampled_from(pool), label="where")
        parent = doc
        for key in where[:-1]:
            parent = parent[key]
        key = where[-1]
        op = data.draw(st.sampled_from(["replace", "replace", "replace", "delete", "truncate"]))
        if op == "delete":
            del parent[key]
        elif op == "truncate" and isinstance(parent[key], list):
            parent[key] = parent[key][: data.draw(st.integers(0, 2))]
        else:
            parent[key] = data.draw(NASTY, label="value")
    return doc


def check_outcome(res, ws, before: dict[str, str], out: Path | None) -> None:
    assert res.traceback is None, res.traceback
    assert res.code in (0, 2), (res.code, res.err[:500])
    if res.code == 2:
        assert res.err.startswith("error:") and res.err.count("error:") == 1, res.err[:500]
        assert len(res.err) < 600
        assert changes(before, snapshot(ws.root)) == [], "a refused command wrote something"
    assert temporaries(ws.root) == []


def fuzz(examples: int) -> settings:
    return settings(
        max_examples=examples,
        deadline=None,
        suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    )


@fuzz(150)
@given(data=st.data())
def test_fuzzed_transforms_info(data, golden, tmp_path_factory, capsys):
    ws = make_workspace(tmp_path_factory.mktemp("fuzz") / "ws", *golden)
    meta = mutate(ws.transforms(), data)
    ws.write_transforms(meta)
    before = snapshot(ws.root)
    res = run_neo(["info", ws.data], capsys)
    check_outcome(res, ws, before, None)
    shutil.rmtree(ws.root)


@fuzz(25)
@given(data=st.data())
def test_fuzzed_transforms_train(data, golden, tmp_path_factory, capsys):
    ws = make_workspace(tmp_path_factory.mktemp("fuzz") / "ws", *golden)
    ws.write_transforms(mutate(ws.transforms(), data))
    before = snapshot(ws.root)
    out = ws.path("s")
    res = run_neo(["train", ws.data, "--out", out, *TINY_TRAIN_ARGS], capsys)
    check_outcome(res, ws, before, out)
    if res.code == 0:
        assert load_scene(out).meta.step == 2
    shutil.rmtree(ws.root)


@fuzz(60)
@given(data=st.data())
def test_fuzzed_scene_json_render(data, golden, tmp_path_factory, capsys):
    ws = make_workspace(tmp_path_factory.mktemp("fuzz") / "ws", *golden)
    meta = ws.scene_json()
    meta.pop("history", None)  # free-form logs: mutating them tells nothing
    mutated = mutate(meta, data)
    (ws.scene / "scene.json").write_text(json.dumps(mutated))
    before = snapshot(ws.root)
    out = ws.path("r")
    res = run_neo(["render", ws.scene, "--out", out, "--views", "eval"], capsys)
    check_outcome(res, ws, before, out)
    if res.code == 0:
        frames = json.loads((out / "transforms.json").read_text())["frames"]
        assert all((out / f["file_path"]).is_file() for f in frames)
    shutil.rmtree(ws.root)


@pytest.mark.parametrize("text", ["", "{", "[]", "null", "0", '{"format": "neoedit.scene/1"}'])
def test_degenerate_scene_json(text, golden, tmp_path, capsys):
    ws = make_workspace(tmp_path / "ws", *golden)
    (ws.scene / "scene.json").write_text(text)
    before = snapshot(ws.root)
    res = run_neo(["render", ws.scene, "--out", ws.path("r")], capsys)
    check_outcome(res, ws, before, ws.path("r"))
    assert res.code == 2
