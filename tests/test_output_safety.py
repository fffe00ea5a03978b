"""Issue 12, the cases a table cannot hold: a disk that refuses writes, unreadable files,
the user's umask, leftovers of crashed runs and very long prompts."""

# ruff: noqa: F811 (the golden fixture is imported and used as an argument)
from __future__ import annotations

import errno
import json
import os
import shutil
from pathlib import Path

import pytest

from neoedit.language.localize import NoMatch
from neoedit.utils import io
from neoedit.utils.io import atomic_directory, atomic_write_json, clean_stale_temporaries
from tests.conftest import tiny_train
from tests.safety_support import (
    TINY_TRAIN_ARGS,
    changes,
    golden,  # noqa: F401 (a fixture)
    make_workspace,
    run_neo,
    snapshot,
    temporaries,
)

IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


def read_only_fs(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every new file fails as on a read-only file system (root ignores chmod)."""

    def refuse(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(io.tempfile, "mkstemp", refuse)


def test_unwritable_out_is_refused_before_training(golden, tmp_path, capsys, monkeypatch):
    ws = make_workspace(tmp_path / "ws", *golden)
    before = snapshot(ws.root)
    read_only_fs(monkeypatch)
    trained = []
    monkeypatch.setattr("neoedit.training.trainer.train", lambda *a, **k: trained.append(1))
    res = run_neo(["train", ws.data, "--out", ws.path("s"), *TINY_TRAIN_ARGS], capsys)
    assert res.code == 2 and "cannot write to" in res.err and "Read-only" in res.err
    assert trained == [] and changes(before, snapshot(ws.root)) == []


@pytest.mark.parametrize("verb", ["render", "eval", "sim"])
def test_unwritable_out_other_verbs(verb, golden, tmp_path, capsys, monkeypatch):
    ws = make_workspace(tmp_path / "ws", *golden)
    spec = ws.write(
        "spec.yaml", "name: s\nobjects: [{name: m, urdf: 'pybullet_data:objects/mug.urdf'}]\n"
    )
    argv = {
        "render": ["render", ws.scene, "--out", ws.path("r")],
        "eval": ["eval", ws.scene, "--data", ws.data, "--json", ws.path("m.json")],
        "sim": ["sim", "scene", spec, "--out", ws.path("sim")],
    }[verb]
    read_only_fs(monkeypatch)
    res = run_neo(argv, capsys)
    assert res.traceback is None and res.code == 2 and "cannot write to" in res.err


@pytest.mark.skipif(IS_ROOT, reason="root ignores file permissions")
def test_read_only_folder_for_real(golden, tmp_path, capsys):
    ws = make_workspace(tmp_path / "ws", *golden)
    locked = ws.path("locked")
    locked.mkdir()
    locked.chmod(0o555)
    try:
        res = run_neo(["render", ws.scene, "--out", locked / "r"], capsys)
        assert res.code == 2 and "cannot write to" in res.err
    finally:
        locked.chmod(0o755)


def test_unreadable_dataset_is_a_message(golden, tmp_path, capsys, monkeypatch):
    ws = make_workspace(tmp_path / "ws", *golden)
    real = Path.read_text

    def deny(self, *args, **kwargs):
        if self.name == "transforms.json":
            raise PermissionError(errno.EACCES, "Permission denied", str(self))
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Path, "read_text", deny)
    res = run_neo(["info", ws.data], capsys)
    assert res.traceback is None and res.code == 2 and "Permission denied" in res.err


def test_unreadable_folder_is_a_message(golden, tmp_path, capsys, monkeypatch):
    ws = make_workspace(tmp_path / "ws", *golden)
    real = Path.is_file

    def deny(self):
        if self.parent == ws.data:
            raise PermissionError(errno.EACCES, "Permission denied", str(self))
        return real(self)

    monkeypatch.setattr(Path, "is_file", deny)
    res = run_neo(["info", ws.data], capsys)
    assert res.traceback is None and res.code == 2 and "Permission denied" in res.err


@pytest.mark.skipif(IS_ROOT, reason="root ignores file permissions")
def test_unreadable_image_for_real(golden, tmp_path, capsys):
    ws = make_workspace(tmp_path / "ws", *golden)
    image = next((ws.data / "images").iterdir())
    image.chmod(0)
    res = run_neo(["info", ws.data], capsys)
    assert res.code == 2 and "error:" in res.err


@pytest.mark.parametrize("mask", [0o022, 0o077, 0o002])
def test_outputs_follow_the_umask(mask, golden, tmp_path, capsys):
    ws = make_workspace(tmp_path / "ws", *golden)
    old = os.umask(mask)
    try:
        res = run_neo(["render", ws.scene, "--out", ws.path("r"), "--views", "eval"], capsys)
        tiny_train(ws.data, ws.path("s"), steps=1)
    finally:
        os.umask(old)
    assert res.code == 0
    for out in (ws.path("r"), ws.path("s")):
        for p in [out, *out.rglob("*")]:
            want = (0o777 if p.is_dir() else 0o666) & ~mask
            assert p.stat().st_mode & 0o777 == want, (p, oct(p.stat().st_mode))


def test_legacy_leftovers_are_removed_by_the_next_run(golden, tmp_path, capsys):
    """What the old writer left after a kill (a hidden ``.NAME.XXXXXXXX.partial`` folder, an
    ``.old`` backup beside a complete scene, a ``.tmp`` file) goes at the next save."""
    ws = make_workspace(tmp_path / "ws", *golden)
    out = ws.path("r")
    for name in (".r.k2j4_x9q.partial", ".r.ab3de8fg.old"):
        (ws.root / name / "images").mkdir(parents=True)
        (ws.root / name / "images" / "x.png").write_bytes(b"x" * 1000)
    (ws.root / ".r.qwertyui.tmp").write_bytes(b"half")
    res = run_neo(["render", ws.scene, "--out", out, "--views", "eval"], capsys)
    assert res.code == 0 and temporaries(ws.root) == []
    assert not any(p.name.startswith(".r.") for p in ws.root.iterdir())


def test_backup_of_a_crashed_swap_is_restored(tmp_path):
    """A crash between the two renames of the fallback swap leaves the previous version
    only under its backup name: the next run puts it back instead of deleting it."""
    final = tmp_path / "r"
    with atomic_directory(final, kind="render") as tmp:
        (tmp / "a.txt").write_text("v1")
    backup = io._temp_path(final, "old")
    os.replace(final, backup)  # the state right after a kill between the renames
    pid_dead = backup.with_name(backup.name.replace(f"-{os.getpid()}-", "-999999999-"))
    os.replace(backup, pid_dead)
    assert clean_stale_temporaries(tmp_path) == [pid_dead]
    assert (final / "a.txt").read_text() == "v1" and temporaries(tmp_path) == []


def test_a_running_writer_is_left_alone(tmp_path):
    """A temporary whose process is alive (another neo writing there) is not touched."""
    busy = tmp_path / f".r.neoedit-{os.getppid()}-0123abcd.partial"
    busy.mkdir()
    assert clean_stale_temporaries(tmp_path) == [] and busy.exists()


def test_json_is_replaced_only_when_it_was_json(tmp_path):
    result = tmp_path / "m.json"
    atomic_write_json(result, {"psnr": 1})
    io.check_writable_output(result, [], "json", overwrite=True)  # an earlier result: asked
    result.write_bytes(b"\x89PNG")
    with pytest.raises(io.NeoError, match="not a previous JSON result"):
        io.check_writable_output(result, [], "json", overwrite=True)


def test_a_json_file_is_replaced_only_with_overwrite_and_never_a_scenes_own(tmp_path):
    """Issue 42: `--json F` replaced a user's config.json, a store's store.json, a version's
    tensors.json without being asked."""
    user = tmp_path / "config.json"
    user.write_text('{"lr": 0.01}')
    with pytest.raises(io.NeoError, match="already exists"):
        io.check_writable_output(user, [], "json", overwrite=False)
    io.check_writable_output(user, [], "json", overwrite=True)  # asked for: a JSON result
    for name in ("store.json", "tensors.json", "scene.json", "transforms.json"):
        own = tmp_path / name.split(".")[0] / name  # each in its own folder
        own.parent.mkdir()
        own.write_text("{}")
        with pytest.raises(io.NeoError, match="not a previous JSON result|is inside a scene"):
            io.check_writable_output(own, [], "json", overwrite=True)
    assert user.read_text() == '{"lr": 0.01}'


def test_a_second_writer_of_one_output_fails_before_its_work(tmp_path):
    """Issue 42: two `neo train` into one --out both said "wrote" and one replaced the other."""
    import subprocess
    import sys

    out = tmp_path / "scene"
    code = (
        "import sys, time; from neoedit.utils.io import check_writable_output; "
        "check_writable_output(sys.argv[1], [], 'scene'); print('held', flush=True); time.sleep(60)"
    )
    writer = subprocess.Popen([sys.executable, "-c", code, str(out)], stdout=subprocess.PIPE)
    try:
        assert writer.stdout.readline().strip() == b"held"
        with pytest.raises(io.NeoError, match="being written by another neo process"):
            io.check_writable_output(tmp_path / "." / "scene", [], "scene")
        io.check_writable_output(tmp_path / "other", [], "scene")  # another output: free
    finally:
        writer.kill()
        writer.wait()
    io.check_writable_output(out, [], "scene")  # a killed writer's lock is released
    io.check_writable_output(out, [], "scene")  # and this process may check it again


def test_no_output_goes_inside_a_scene_or_a_store(tmp_path):
    scene = tmp_path / "scene"
    scene.mkdir()
    (scene / "scene.json").write_text('{"format": "neoedit.scene/1"}')
    store = tmp_path / "store"
    (store / "step_1").mkdir(parents=True)
    (store / "store.json").write_text("{}")
    for out, kind in (
        (scene / "m.json", "json"),
        (scene / "renders", "render"),
        (store / "step_1" / "sub", "scene"),
        (store / "grasps", "grasp"),
    ):
        with pytest.raises(io.NeoError, match="is inside a scene"):
            io.check_writable_output(out, [], kind, overwrite=True)
        assert not out.exists()


def test_out_of_memory_and_a_full_disk_are_one_line(tmp_path, capsys, monkeypatch):
    from neoedit.cli.data import InfoCommand

    for raised, expected in (
        (
            RuntimeError(
                "[enforce fail at alloc_cpu.cpp:117] DefaultCPUAllocator: not enough "
                "memory: you tried to allocate 99 bytes."
            ),
            "out of memory",
        ),
        (
            RuntimeError("Error while serializing: IoError(No space left on device (os error 28))"),
            "the disk is full",
        ),
    ):

        def fail(self, raised=raised):
            raise raised

        monkeypatch.setattr(InfoCommand, "run", fail)
        res = run_neo(["info", tmp_path], capsys)
        assert res.code == 2 and res.traceback is None, res
        assert expected in res.err and res.err.count("error:") == 1
    monkeypatch.setattr(InfoCommand, "run", lambda self: 1 / 0)  # a bug stays a traceback
    assert run_neo(["info", tmp_path], capsys).traceback is not None


def test_sim_benchmark_writes_only_into_a_new_empty_or_earlier_suite_folder(tmp_path, capsys):
    user = tmp_path / "mine"
    user.mkdir()
    (user / "notes.txt").write_text("keep")
    argv = ["sim", "benchmark", "--profile", "small", "--only", "removal_1", "--out"]
    res = run_neo([*argv, user], capsys)
    assert res.code == 2 and "holds no earlier `neo sim benchmark` output" in res.err
    assert [p.name for p in user.iterdir()] == ["notes.txt"]
    earlier = tmp_path / "suite"  # written before outputs were marked: its suite.json says so
    earlier.mkdir()
    (earlier / "suite.json").write_text('{"profile": "small", "seed": 0, "scenes": []}')
    from neoedit.cli.sim import _is_suite

    assert _is_suite(earlier) and not _is_suite(user)


def test_a_suite_rerun_keeps_its_figures_and_refuses_another_profile_or_seed(tmp_path, capsys):
    """Re-running into an earlier suite skips its scenes and keeps what suite.json said of
    them (strict JSON: no NaN for a skipped scene's time); a run of another profile or seed
    would list the old scans under its own name, so it is refused and nothing changes."""

    def strict(path: Path) -> dict:
        def refuse(name: str):
            raise ValueError(f"not JSON: {name}")

        return json.loads(path.read_text(), parse_constant=refuse)

    suite = tmp_path / "suite"
    argv = ["sim", "benchmark", "--profile", "small", "--only", "removal_1", "--out", suite]
    assert run_neo(argv, capsys).code == 0
    first = strict(suite / "suite.json")
    res = run_neo(argv, capsys)
    assert res.code == 0 and "exists, skipped" in res.out
    assert strict(suite / "suite.json") == first  # its time is the one it was made in
    before = (suite / "suite.json").read_bytes()
    for other in (["--seed", "1"], ["--profile", "standard"]):
        res = run_neo([*argv, *other], capsys)
        assert res.code == 2 and "holds the small suite of seed 0" in res.err, other
        assert (suite / "suite.json").read_bytes() == before
    from neoedit.cli.sim import SimBenchmarkCommand

    # regenerating every scene of it (--overwrite, no --only) keeps nothing of it: allowed
    whole = SimBenchmarkCommand(out=suite, profile="small", seed=1, overwrite=True)
    assert whole._earlier_rows() == {}
    # a suite written before this check (a NaN time for a skipped scene) is read as no time
    old = json.loads(before)
    old["scenes"][0]["seconds"] = float("nan")
    (suite / "suite.json").write_text(json.dumps(old))
    rows = SimBenchmarkCommand(out=suite, profile="small")._earlier_rows()
    assert rows["removal_1"]["seconds"] is None


def test_replacing_needs_a_neoedit_output_even_in_the_api(tmp_path):
    user = tmp_path / "photos"
    user.mkdir()
    (user / "cat.jpg").write_bytes(b"cat")
    with pytest.raises(io.NeoError, match="not a neoedit output"):
        with atomic_directory(user, overwrite=True, kind="scene"):
            pass
    assert (user / "cat.jpg").read_bytes() == b"cat" and temporaries(tmp_path) == []


def test_long_prompt_is_shortened_in_messages():
    prompt = "red mug " * 1250
    message = str(NoMatch(prompt, 0.1, 0.5))
    assert len(message) < 200 and "10000 characters" in message


def test_markup_in_a_message_is_printed_as_text(tmp_path, capsys):
    res = run_neo(["info", tmp_path / "[bold]x[/]"], capsys)
    assert res.code == 2 and "[bold]x[/]" in res.err


def test_markup_in_a_path_is_printed_as_text(sim_root, tmp_path, capsys):
    """Issue 42: a folder named like rich markup raised MarkupError or lost its brackets."""
    odd = tmp_path / "scan [x] [/]"
    shutil.copytree(sim_root / "removal_1" / "pre", odd)
    res = run_neo(["info", odd], capsys)
    assert res.code == 0 and res.traceback is None, res
    out = " ".join(res.out.split())
    assert out.count("scan [x] [/]") == 2, out  # the header and the `neo train` line


def test_markup_in_an_output_path_is_printed_as_text(sim_root, tmp_path, capsys):
    """The third probe: `neo train --out 'T[/]9'` wrote the scene, then its "wrote" line
    raised MarkupError (exit 1); `[red]y[/red]` lost its brackets."""
    out = tmp_path / "T [red]y[/red] [/]"
    res = run_neo(["train", sim_root / "removal_1" / "pre", "--out", out, *TINY_TRAIN_ARGS], capsys)
    assert res.code == 0 and res.traceback is None, res
    assert f"wrote {out}" in " ".join(res.out.split())


def test_input_scene_is_untouched_by_every_refusal_and_success(golden, tmp_path, capsys):
    """The input scene stays byte-identical through renders, evaluations and edits."""
    ws = make_workspace(tmp_path / "ws", *golden)
    shutil.copy(ws.scene / "scene.json", ws.path("scene.json.bak"))
    before = snapshot(ws.scene)
    ws.write("mug.json", {"center": [0.076, -0.098, 0.046], "size": [0.07, 0.1, 0.09]})
    for argv in (
        ["render", ws.scene, "--out", ws.path("r")],
        ["eval", ws.scene, "--data", ws.data, "--json", ws.path("m.json")],
        [
            "remove",
            ws.scene,
            "--box",
            ws.path("mug.json"),
            "--out",
            ws.path("v"),
            "--no-inpaint",
            "--no-report",
        ],
        ["remove", ws.scene, "--box", ws.path("mug.json"), "--out", ws.scene, "--overwrite"],
    ):
        assert run_neo(argv, capsys).traceback is None
    assert changes(before, snapshot(ws.scene)) == []


def test_a_mount_point_out_is_refused_before_work(golden, tmp_path, capsys, monkeypatch):
    """An empty folder that is a mount point cannot be replaced by a rename: refused at the
    checks, not after the training (os.path.ismount stands in for a real mount)."""
    ws = make_workspace(tmp_path / "ws", *golden)
    mount = ws.path("mnt")
    mount.mkdir()
    real = os.path.ismount
    monkeypatch.setattr(io.os.path, "ismount", lambda p: Path(p) == mount or real(p))
    res = run_neo(["train", ws.data, "--out", mount, *TINY_TRAIN_ARGS], capsys)
    assert res.code == 2 and "is a mount point" in res.err and not any(mount.iterdir())


def test_a_work_folder_a_killed_process_left_is_removed_by_the_next_write(tmp_path):
    out = tmp_path / "dataset"
    with io.work_directory(out) as work:
        (work / "frames").mkdir()
        assert work.parent == tmp_path and work.name.startswith(".dataset.neoedit-")
    assert not work.exists()
    dead = tmp_path / ".dataset.neoedit-999999-0badc0de.tmp"  # what a SIGKILL leaves
    (dead / "frames").mkdir(parents=True)
    io.check_writable_output(tmp_path / "other", kind="dataset")
    assert not dead.exists()


def test_parse_errors_are_condensed_to_a_few_lines():
    from neoedit.cli._parse import condense

    box = "\n".join(
        [
            "╭─ Unrecognized options ─────────╮",
            "│ Unrecognized options: --stepz  │",
            "│ ────────────────────────────── │",
            "│ Perhaps you meant:             │",
            *[f"│     --a.b{i}.steps INT  │\n│         help {i} │" for i in range(40)],
            "│ ────────────────────────────── │",
            "│ For full helptext, run neo move --help │",
            "╰────────────────────────────────╯",
        ]
    )
    plain = box.replace("╭─ Unrecognized options ─────────╮", " Unrecognized options\n ----- ")
    for text in (box, plain.replace("│", " ").replace("─", "-").replace("╰", " ").replace("╯", "")):
        lines = condense(text, "neo move").splitlines()
        assert lines[0] == "error: Unrecognized options: --stepz"
        assert lines[1] == "  did you mean: " + ", ".join(f"--a.b{i}.steps" for i in range(5))
        assert lines[2] == "  every option: neo move --help" and len(lines) == 3


def _tyro_box(rows: list[str]) -> str:
    """``rows`` drawn in tyro's error box, as a UTF-8 terminal shows it."""
    return "\n".join(["╭─ Unrecognized options ─╮", *(f"│ {r} │" for r in rows), "╰──╯"])


def test_a_suggested_option_of_another_command_is_named_with_it():
    """tyro suggests similar options of every verb; one that belongs to another verb must
    not read as an option of this one (``neo sim benchmark --scenes`` said "did you mean:
    --scenes")."""
    from neoedit.cli._parse import condense

    rows = [
        "Unrecognized or misplaced options: --scenes (applied to neo sim benchmark)",
        "───",
        "Perhaps you meant:",
        "    --scenes [STR [STR ...]]",
        "        Scenes to run. (default: )",
        "        in neo bench --help",
        "    --only [STR [STR ...]]",
        "        Generate only these scenes. (default: )",
        "        in neo sim benchmark --help",
        "───",
        "For full helptext, run neo --help",
    ]
    text = _tyro_box(rows)
    lines = condense(text, "neo sim benchmark").splitlines()
    assert lines[1] == "  did you mean: --only, --scenes (an option of neo bench)"
    assert lines[2] == "  every option: neo sim benchmark --help"
    # without a verb every verb's options are fair suggestions
    assert condense(text, "neo").splitlines()[1] == "  did you mean: --scenes, --only"


def test_a_help_line_that_starts_with_an_option_is_not_suggested():
    """tyro wraps help text freely: a help line may start with an option's name ('--no-inpaint,
    the DFF-style baseline'); only the rows that name options are suggestions (metavars and
    choices included)."""
    from neoedit.cli._parse import condense

    rows = [
        "Unrecognized options: --no-inpaint",
        "───",
        "Perhaps you meant:",
        "    --edit.remove.inpaint, --edit.remove.no-inpaint",
        "        Complete what the object hid; with",
        "        --no-inpaint, the instant preview. (default: True)",
        "        in neo move --help",
        "    --profile {small,standard}",
        "        --profile small is for tests. (default: small)",
        "        in neo move --help",
        "    --json {None}|PATH",
        "        in neo move --help",
        "    --scenes [STR [STR ...]]",
        "        in neo move --help",
        "───",
        "For full helptext, run neo move --help",
    ]
    text = _tyro_box(rows)
    lines = condense(text, "neo move").splitlines()
    assert lines[1] == "  did you mean: --edit.remove.inpaint, --profile, --json, --scenes"
