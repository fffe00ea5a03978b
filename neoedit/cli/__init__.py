"""The ``neo`` command line. Every verb is a dataclass config (tyro) with a ``run()`` method."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Annotated, Union

import tyro
from rich.console import Console

from neoedit.cli.data import InfoCommand
from neoedit.cli.edit import MoveCommand, RemoveCommand
from neoedit.cli.field import EvalCommand, RenderCommand, TrainCommand
from neoedit.cli.grasp import GraspCommand
from neoedit.cli.history import DiffCommand, LogCommand, RestoreCommand
from neoedit.cli.language import QueryCommand
from neoedit.cli.plan import PlanCommand
from neoedit.cli.sim import SimBenchmarkCommand, SimExecuteCommand, SimSceneCommand
from neoedit.errors import NeoError
from neoedit.utils.validate import check_device, user_message

SimCommands = Annotated[
    Union[  # noqa: UP007 (tyro reads the Union)
        Annotated[SimSceneCommand, tyro.conf.subcommand("scene")],
        Annotated[SimBenchmarkCommand, tyro.conf.subcommand("benchmark")],
        Annotated[SimExecuteCommand, tyro.conf.subcommand("execute")],
    ],
    tyro.conf.subcommand(
        "sim", description="Simulated tabletop scans before/after manipulation (NEO-Sim)."
    ),
]

Commands = Union[  # noqa: UP007
    SimCommands,
    Annotated[InfoCommand, tyro.conf.subcommand("info")],
    Annotated[TrainCommand, tyro.conf.subcommand("train")],
    Annotated[RenderCommand, tyro.conf.subcommand("render")],
    Annotated[EvalCommand, tyro.conf.subcommand("eval")],
    Annotated[QueryCommand, tyro.conf.subcommand("query")],
    Annotated[RemoveCommand, tyro.conf.subcommand("remove")],
    Annotated[MoveCommand, tyro.conf.subcommand("move")],
    Annotated[PlanCommand, tyro.conf.subcommand("plan")],
    Annotated[GraspCommand, tyro.conf.subcommand("grasp")],
    Annotated[LogCommand, tyro.conf.subcommand("log")],
    Annotated[RestoreCommand, tyro.conf.subcommand("restore")],
    Annotated[DiffCommand, tyro.conf.subcommand("diff")],
]


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``neo``; returns the exit status (0 ok, 2 bad input, 130 interrupted)."""
    command = tyro.cli(Commands, prog="neo", args=argv)
    err = Console(stderr=True)
    try:
        check_device(getattr(command, "device", "auto"))
        command.run()
    except NeoError as e:
        err.print(f"[bold red]error:[/] {user_message(e)}", highlight=False)
        return 2
    except OSError as e:  # a file that cannot be read or written (permissions, disk full, ...)
        err.print(f"[bold red]error:[/] {user_message(e)}", highlight=False)
        return 2
    except SystemExit as e:  # a verb's own non-zero status (e.g. query: no match)
        return int(e.code or 0)
    except KeyboardInterrupt:
        err.print("[yellow]interrupted[/]")
        return 130
    return 0


def entry() -> None:
    sys.exit(main())
