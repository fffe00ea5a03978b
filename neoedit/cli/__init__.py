"""The ``neo`` command line. Every verb is a dataclass config (tyro) with a ``run()`` method."""

from __future__ import annotations

import contextlib
import io
import os
import sys
import warnings
from collections.abc import Iterator, Sequence
from typing import Any, Protocol

from rich.console import Console
from rich.markup import escape

from neoedit.cli._parse import parse
from neoedit.errors import NeoError, NeoWarning
from neoedit.utils.options import check_options
from neoedit.utils.progress import QUIET_ENV
from neoedit.utils.threads import configure_threads, parse_threads
from neoedit.utils.validate import check_device, resource_message, user_message

VERBS = {
    "process": "neoedit.cli.importer:ProcessCommand",
    "register": "neoedit.cli.importer:RegisterCommand",
    "info": "neoedit.cli.data:InfoCommand",
    "train": "neoedit.cli.field:TrainCommand",
    "render": "neoedit.cli.field:RenderCommand",
    "eval": "neoedit.cli.field:EvalCommand",
    "query": "neoedit.cli.language:QueryCommand",
    "remove": "neoedit.cli.edit:RemoveCommand",
    "move": "neoedit.cli.edit:MoveCommand",
    "plan": "neoedit.cli.plan:PlanCommand",
    "grasp": "neoedit.cli.grasp:GraspCommand",
    "log": "neoedit.cli.history:LogCommand",
    "restore": "neoedit.cli.history:RestoreCommand",
    "diff": "neoedit.cli.history:DiffCommand",
    "view": "neoedit.cli.view:ViewCommand",
    "bench": "neoedit.cli.bench:BenchCommand",
}
"""The verbs without verbs of their own -> where their command lives: ``neo query ...``
imports only the query's module (every verb's module together: 0.5 s more per command,
the edit methods and the baselines among them). ``sim`` and ``import``, help and errors
go through :data:`neoedit.cli._commands.Commands`, so they read as they always did."""

GROUPS = ("sim", "import")
"""The verbs with verbs of their own (``neo sim scene``, ``neo import colmap``)."""


def __getattr__(name: str) -> Any:
    if name == "Commands":  # the whole CLI, for help, errors and tests
        from neoedit.cli._commands import Commands

        return Commands
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


THREADS_HELP = (
    "Every verb also takes --threads N (or NEO_THREADS=N): CPU threads of torch and numba "
    "(default: the cores this process may use); --verbose: also show the model "
    "libraries' own loading bars and logs; --quiet: no progress bars, only results and errors."
)


def pop_threads(argv: list[str]) -> tuple[list[str], str | None]:
    """``--threads N`` / ``--threads=N`` anywhere in ``argv`` (every verb takes it) -> the
    remaining arguments and its value (None when absent; '' when the value is missing)."""
    rest: list[str] = []
    value: str | None = None
    i = 0
    while i < len(argv):
        arg = argv[i]
        if arg == "--threads":
            value = argv[i + 1] if i + 1 < len(argv) else ""
            i += 2
            continue
        if arg.startswith("--threads="):
            value = arg.split("=", 1)[1]
        else:
            rest.append(arg)
        i += 1
    return rest, value


def quiet_third_party() -> None:
    """Only neoedit's own progress and messages: the model libraries' download / loading
    bars and info logs stay off (set before they are imported; --verbose keeps them)."""
    os.environ.setdefault("HF_HUB_DISABLE_PROGRESS_BARS", "1")
    os.environ.setdefault("TRANSFORMERS_VERBOSITY", "error")
    os.environ.setdefault("DIFFUSERS_VERBOSITY", "error")
    os.environ.setdefault("TOKENIZERS_PARALLELISM", "false")
    os.environ.setdefault("NEO_QUIET_THIRD_PARTY", "1")  # e.g. pybullet's load banner


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``neo``; returns the exit status (0 ok; 1 a finding, not a fault: a
    prompt matched no object, no collision-free grasp, a failed ``neo sim execute``, failed
    ``neo bench`` units; 2 bad input or an error; 130 interrupted)."""
    args, threads = pop_threads(list(sys.argv[1:] if argv is None else argv))
    quiet = "--quiet" in args  # results and errors only: no progress bars
    if quiet and "--verbose" in args:
        Console(stderr=True).print(
            "[bold red]error:[/] --quiet and --verbose ask for opposite logs: give one of them",
            highlight=False,
        )
        return 2
    args = [a for a in args if a != "--quiet"]
    if "--verbose" in args:
        args = [a for a in args if a != "--verbose"]
    else:
        quiet_third_party()
    try:  # before the arguments are read as a command ('neo --threads train' took 'train')
        n_threads = None if threads is None else parse_threads(threads)
    except NeoError as e:
        Console(stderr=True).print(f"[bold red]error:[/] {escape(str(e))}", highlight=False)
        return 2
    unknown = _unknown_verb(args)
    if unknown is not None:
        Console(stderr=True).print(f"[bold red]error:[/] {escape(unknown)}", highlight=False)
        return 2
    command = _parse_one_verb(args)
    if command is None:  # help, a group verb, or an error: the whole CLI says it as always
        from neoedit.cli._commands import Commands

        command = parse(Commands, args, THREADS_HELP)
    misread = misread_prompt(args, command)
    if misread is not None:
        Console(stderr=True).print(f"[bold red]error:[/] {escape(misread)}", highlight=False)
        return 2
    with _env(QUIET_ENV, "1" if quiet else os.environ.get(QUIET_ENV)):
        return _run(command, n_threads)


def _unknown_verb(args: list[str]) -> str | None:
    """The message for a first word that is no verb (tyro calls it an unrecognised
    option); None when it is one, or an option."""
    if not args or args[0].startswith("-") or args[0] in VERBS or args[0] in GROUPS:
        return None
    import difflib

    known = sorted([*VERBS, *GROUPS])
    close = difflib.get_close_matches(args[0], known, n=1)
    hint = f"did you mean '{close[0]}'? " if close else ""
    if args[0] == "help":
        hint = "for help: neo --help or neo COMMAND --help; "
    return f"'{args[0]}' is not a neo command; {hint}the commands: {', '.join(known)}"


BOOL_WORDS = frozenset({"true", "false", "yes", "no", "on", "off", "0", "1"})


def misread_prompt(args: list[str], command: Any) -> str | None:
    """What went wrong when a command's prompt is really a mistyped option: an
    ``--inpaint=False`` no verb knows, or the 'true' after an on/off flag (``--no-inpaint
    true``), which the prompt argument swallowed (the command would look for an object
    named 'true'); None for a real prompt."""
    prompt = getattr(command, "prompt", None)
    if not isinstance(prompt, str):
        return None
    if prompt.startswith("--"):
        return (
            f"{prompt} is not an option of this command (it was read as the prompt); on/off "
            "options take no value: write --NAME or --no-NAME"
        )
    if prompt.lower() not in BOOL_WORDS:
        return None
    for i, arg in enumerate(args):
        name, _, value = arg.partition("=")
        if arg == prompt and i > 0 and args[i - 1].startswith("--"):
            name = args[i - 1]
        elif not (arg.startswith("--") and value == prompt):
            continue
        off = prompt.lower() in ("false", "no", "off", "0")
        negated = name.startswith("--no-")
        plain = name.removeprefix("--").removeprefix("no-")
        meant = f"--no-{plain}" if off != negated else f"--{plain}"
        return f"{name} takes no value ('{prompt}' was read as the prompt): write {meant}"
    return None


def _parse_one_verb(args: list[str]) -> Any:
    """The command of ``args`` parsed with its own verb's module only; None when this fast
    path does not apply (no such verb, ``--help``) or the arguments do not parse."""
    if not args or args[0] not in VERBS or any(a in ("-h", "--help") for a in args):
        return None
    import importlib

    import tyro

    module, name = VERBS[args[0]].split(":")
    command = getattr(importlib.import_module(module), name)
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        try:
            return tyro.cli(command, prog=f"neo {args[0]}", args=args[1:])
        except SystemExit:
            return None


@contextlib.contextmanager
def _env(name: str, value: str | None) -> Iterator[None]:
    """``name`` set to ``value`` (unset for None) while inside; restored after."""
    before = os.environ.get(name)
    if value is None:
        os.environ.pop(name, None)
    else:
        os.environ[name] = value
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = before


class _Command(Protocol):
    def run(self) -> None: ...


@contextlib.contextmanager
def _warnings_as_lines(err: Console) -> Iterator[None]:
    """neoedit's own warnings (:class:`NeoWarning`) print as one ``warning:`` line, not as
    Python's file:line report; other libraries' warnings are shown as they always are."""
    with warnings.catch_warnings():  # restores the previous showwarning on the way out
        shown = warnings.showwarning

        def show(message: Any, category: type[Warning], *args: Any, **kwargs: Any) -> None:
            if issubclass(category, NeoWarning):
                err.print(f"[yellow]warning:[/] {escape(str(message))}", highlight=False)
            else:
                shown(message, category, *args, **kwargs)

        warnings.showwarning = show
        yield


def _run(command: _Command, threads: int | None) -> int:
    """Run a parsed command; errors -> one line on stderr and the exit status."""
    err = Console(stderr=True)
    try:
        configure_threads(threads)
        check_options(command)
        check_device(getattr(command, "device", "auto"))
        with _warnings_as_lines(err):
            command.run()
    except (NeoError, OSError) as e:  # OSError: a file that cannot be read or written
        err.print(f"[bold red]error:[/] {user_message(e)}", highlight=False)
        return getattr(e, "exit_code", 2)
    except Exception as e:
        message = resource_message(e)  # out of memory, disk full: one line, no traceback
        if message is None:
            raise
        err.print(f"[bold red]error:[/] {message}", highlight=False)
        return 2
    except SystemExit as e:  # a verb's own non-zero status (e.g. query: no match)
        return int(e.code or 0)
    except KeyboardInterrupt:
        err.print("[yellow]interrupted[/]")
        return 130
    return 0


class _ReaderMayLeave:
    """stdout or stderr of a command whose reader may stop reading (``neo grasp ... | head
    -1``, ``2>&1 | head``): once the pipe is closed, what is printed goes nowhere and the
    command finishes its work (its files written, its exit status its own) instead of dying
    of a BrokenPipeError."""

    def __init__(self, stream: Any):
        self._stream = stream

    def _gone(self) -> None:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, self._stream.fileno())  # what is still buffered flushes there
        os.close(devnull)

    def write(self, text: str) -> int:
        try:
            return int(self._stream.write(text))
        except BrokenPipeError:
            self._gone()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._gone()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def entry() -> None:
    if not isinstance(sys.stdout, _ReaderMayLeave) and sys.stdout is not None:
        sys.stdout = _ReaderMayLeave(sys.stdout)
    if not isinstance(sys.stderr, _ReaderMayLeave) and sys.stderr is not None:
        sys.stderr = _ReaderMayLeave(sys.stderr)
    sys.exit(main())
