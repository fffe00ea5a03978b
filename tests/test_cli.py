"""The neo command line: help for every verb, clean errors, atomic output."""

import subprocess
import sys
from pathlib import Path

import pytest

from neoedit.cli import main

VERBS = [["sim", "scene"], ["sim", "benchmark"], ["info"], ["train"], ["render"], ["eval"]]


@pytest.mark.parametrize("verb", VERBS)
def test_help(verb, capsys):
    with pytest.raises(SystemExit) as e:
        main([*verb, "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "usage: neo" in out


def test_benchmark_help_lists_options_with_defaults(capsys):
    with pytest.raises(SystemExit):
        main(["sim", "benchmark", "--help"])
    out = capsys.readouterr().out
    for option in ("--out", "--profile", "--seed", "--only", "--overwrite"):
        assert option in out
    assert "standard" in out  # the default profile is shown


def test_bad_spec_exits_nonzero_without_output(tmp_path: Path, capsys):
    spec = tmp_path / "bad.yaml"
    spec.write_text(
        "name: s\nobjects:\n  - name: mug\n    urdf: pybullet_data:objects/mug.urdf\n    scale: -1\n"
    )
    assert main(["sim", "scene", str(spec), "--out", str(tmp_path / "out")]) == 2
    assert "objects[0].scale" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_unknown_scene_name(tmp_path: Path, capsys):
    assert (
        main(["sim", "benchmark", "--profile", "small", "--out", str(tmp_path), "--only", "nope"])
        == 2
    )
    assert "unknown scene" in capsys.readouterr().err


def test_info_on_sim_scan(sim_root: Path, capsys):
    assert main(["info", str(sim_root / "removal_1" / "pre")]) == 0
    out = capsys.readouterr().out
    assert "13 frames of 64x48" in out and "red mug" in out


def test_console_script_runs():
    result = subprocess.run(
        [sys.executable, "-m", "neoedit", "--help"], capture_output=True, text=True
    )
    assert result.returncode == 0 and "sim" in result.stdout
