"""Every verb of ``neo`` in one tyro Union (importing this imports every verb's module;
``neo VERB`` alone imports only its own: :data:`neoedit.cli.VERBS`)."""

from __future__ import annotations

from typing import Annotated, Union

import tyro

from neoedit.cli.bench import BenchCommand
from neoedit.cli.data import InfoCommand
from neoedit.cli.edit import MoveCommand, RemoveCommand
from neoedit.cli.field import EvalCommand, RenderCommand, TrainCommand
from neoedit.cli.grasp import GraspCommand
from neoedit.cli.history import DiffCommand, LogCommand, RestoreCommand
from neoedit.cli.importer import ImportCommands, ProcessCommand, RegisterCommand
from neoedit.cli.language import QueryCommand
from neoedit.cli.plan import PlanCommand
from neoedit.cli.sim import SimBenchmarkCommand, SimExecuteCommand, SimSceneCommand
from neoedit.cli.view import ViewCommand

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
    ImportCommands,
    Annotated[ProcessCommand, tyro.conf.subcommand("process")],
    Annotated[RegisterCommand, tyro.conf.subcommand("register")],
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
    Annotated[ViewCommand, tyro.conf.subcommand("view")],
    Annotated[BenchCommand, tyro.conf.subcommand("bench")],
]
