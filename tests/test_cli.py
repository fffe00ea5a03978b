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


def test_long_work_without_a_terminal_logs_plain_progress_lines(monkeypatch, capsys):
    """In a log file (no terminal) a long task prints a plain line on stderr every tenth of
    the way, the last one at 100 %; a short one prints nothing; stdout stays clean."""
    from neoedit.utils import progress

    now = [0.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: now[0])
    bar = progress._ListenedProgress(get_time=lambda: now[0], transient=True)
    with bar:
        quick = bar.add_task("quick", total=4, status="")
        for _ in range(4):
            now[0] += 0.5  # 2 s in all: under LOG_AFTER_S
            bar.advance(quick)
        slow = bar.add_task("train", total=100, status="")
        for step in range(100):
            now[0] += 1.0
            bar.update(slow, advance=1, status=f"PSNR {20 + step / 10:.1f} dB")
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert not any(line.startswith("quick") for line in lines)
    assert lines[0].startswith("train 5/100 (5 %)") and "PSNR 20.4 dB" in lines[0]
    assert lines[1].startswith("train 15/100 (15 %)")  # a tenth of the way later
    assert lines[-1].startswith("train 100/100 (100 %) · 0:01:40 elapsed")
    assert len(lines) == 11 and "━" not in err and "train" not in out


def test_each_verb_is_found_where_the_whole_cli_has_it():
    """neoedit.cli.VERBS (``neo VERB`` imports only its own module) names the same command
    class as the whole CLI's Union for every verb without verbs of its own."""
    import importlib
    from typing import get_args

    from neoedit.cli import VERBS, Commands

    whole = {}
    for option in get_args(Commands):
        cls, *markers = get_args(option) or (option,)
        for marker in markers:
            name = getattr(marker, "name", None)
            if isinstance(name, str) and isinstance(cls, type):
                whole[name] = cls
    assert set(VERBS) == set(whole) - {"sim", "import"}
    for verb, where in VERBS.items():
        module, name = where.split(":")
        assert getattr(importlib.import_module(module), name) is whole[verb], verb


@pytest.mark.parametrize(
    "args",
    [
        ["query", "S", "red mug", "--views", "0", "--query.eps-m", "0.02"],
        ["move", "S", "mug", "--translate", "0.1", "0", "0", "--yaw", "30", "--out", "O"],
        ["train", "D", "--out", "O", "--max-steps", "7", "--field.room", "True"],
        ["bench", "--out", "B", "--scenes", "removal_1", "--keep-versions"],
        ["log", "S"],
    ],
)
def test_one_verb_parses_as_the_whole_cli_does(args):
    from neoedit.cli import Commands, _parse_one_verb
    from neoedit.cli._parse import parse

    fast = _parse_one_verb(args)
    assert fast is not None and fast == parse(Commands, args, "")


def test_a_verb_imports_only_its_own_module(tmp_path: Path):
    """`neo log` does not import the edit methods, the baselines or the other verbs."""
    code = (
        "import sys\nfrom neoedit.cli import main\n"
        f"main(['log', {str(tmp_path / 'none')!r}])\n"
        "print(sorted(m for m in ('neoedit.cli.edit', 'neoedit.bench.seal3d', "
        "'neoedit.edit.remove', 'neoedit.cli.sim', 'neoedit.cli.field') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout + out.stderr


def test_a_reader_that_leaves_early_is_no_error(tmp_path: Path):
    """``neo ... | head -1``: the reader closes the pipe before the command prints; the
    command finishes (its own exit status, its files) without a BrokenPipeError."""
    for args in (["grasp", "--help"], ["sim", "scene", "--help"]):
        proc = subprocess.Popen(
            [sys.executable, "-m", "neoedit", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        assert proc.stdout is not None and proc.stderr is not None
        proc.stdout.close()  # gone before the command has started
        err = proc.stderr.read().decode()
        assert proc.wait(timeout=120) == 0, err
        assert "Traceback" not in err and "BrokenPipe" not in err, err


def test_a_reader_that_leaves_early_is_no_error_on_stderr_too():
    """``neo ... 2>&1 | head`` and ``neo ... 2>&1 >/dev/null | head``: errors written to a
    closed pipe leave the command's own exit status (2 for a refused input), not Python's 1
    or 120 for a broken pipe."""
    for stdout in (None, subprocess.DEVNULL):  # stderr with stdout, stderr alone
        proc = subprocess.Popen(
            [sys.executable, "-m", "neoedit", "log", "/nonexistent_store"],
            stdout=subprocess.PIPE if stdout is None else stdout,
            stderr=subprocess.STDOUT if stdout is None else subprocess.PIPE,
        )
        pipe = proc.stdout if stdout is None else proc.stderr
        assert pipe is not None
        pipe.close()
        assert proc.wait(timeout=120) == 2, stdout
