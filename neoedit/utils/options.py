"""Range rules for every numeric option of every command, checked in one place before a
command starts (``neo`` runs :func:`check_options` on the parsed command).

The rules follow the option's name and default, so a new config field is covered without
registering it: every number finite; a field whose default is >= 0 never negative (unless it
is a signed quantity by nature: angles, offsets, "auto" sentinels); rates, sizes and counts
that mean nothing at zero strictly positive; fractions within [0, 1]; and the hard limits of
:data:`neoedit.utils.validate.BOUNDS`. Command-specific checks (a box inside the scene, a
prompt that is not empty) still run in the commands.
"""

from __future__ import annotations

import dataclasses
import math
import re
import typing
from collections.abc import Sequence
from typing import Any

from neoedit.errors import NeoError
from neoedit.utils.validate import check_bound

SIGNED = frozenset(
    {
        "yaw",
        "yaw_deg",
        "up",  # a direction: any sign
        "azimuth_offset_deg",
        "elevation_min_deg",
        "elevation_max_deg",
        "density_bias",
        "near_m",  # < 0: from the scene box
        "radius_m",  # < 0: automatic
        "depth_loss_weight",  # < 0: automatic
        "sparsity_loss_weight",  # < 0: automatic
    }
)
"""Numeric options that may be negative although their default is not."""

DIRECTIONS = frozenset({"up"})
"""Vector options that name a direction (never the zero vector)."""

POSITIVE = frozenset(
    {
        "lr",
        "eps_m",
        "voxel_m",
        "image_scale",
        "max_scale",
        "rays",
        "batch",
        "rays_per_batch",
        "chunk_rays",
        "fps",
        "max_side",
        "max_image_size",
        "match_width_px",
        "max_width_m",
        "collision_step_m",
        "opacity_step_m",
        "min_samples",
        "span_samples",
        "iterations",
        "workers",
        "downscale",
        "holdout_every",
        "max_minutes",
        "lr_final_factor",
        "sparsity_points",
        "friction",
    }
)
"""Options for which zero means nothing (a rate, a size, a count of work)."""

OWN_BOUNDS = frozenset({"max_steps"})
"""Options whose bounds depend on others, checked by their command alone (``--max-steps``:
at least 1, or 0 with ``--resume``), so that -1 and 0 get the same message."""

MAX_INT = 2**31 - 1
"""Largest whole-number option (steps, counts): beyond it torch and numpy overflow."""
SEED_RANGE = 2**32
"""Seeds are in [0, 2^32): every seed numpy accepts (torch takes more)."""
MAX_FLOAT = 1e12
"""Largest size of a real-valued option: far beyond any metre, weight or rate that means
something, well inside float32 (the field's tensors), where 1e300 overflowed. (A yaw has
its own range, in degrees, checked by its command with a message that says so.)"""

_UNIT = re.compile(r"(fraction|quantile|share|decay|opacity|focus|similarity)$")


def changed_options(cfg: Any, default: Any, used: Sequence[str] = ()) -> list[str]:
    """The options of config ``cfg`` set away from ``default`` (the same dataclass) that are
    not under a dotted name in ``used``, spelt as set: 'distill.field_steps', 'no_carry'
    for an on/off option turned off (what a command refuses when it would ignore them)."""
    names = []
    for name, value, ref in _leaves(cfg, default):
        if value == ref or any(name == u or name.startswith(u + ".") for u in used):
            continue
        head, _, last = name.rpartition(".")
        names.append(f"{head}.no_{last}".lstrip(".") if value is False else name)
    return names


def _leaves(cfg: Any, default: Any, prefix: str = ""):
    """(dotted name, value, default) of every option of a nested config dataclass."""
    for f in dataclasses.fields(cfg):
        value, ref = getattr(cfg, f.name), getattr(default, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            yield from _leaves(value, ref, f"{prefix}{f.name}.")
        else:
            yield f"{prefix}{f.name}", value, ref


def option_path(where: str) -> tuple[str, ...]:
    """A command-line prefix as :func:`check_options`' path: '--edit.remove' ->
    ('edit', 'remove'); '' -> ()."""
    return tuple(where.removeprefix("--").replace("-", "_").split(".")) if where else ()


def flag(path: tuple[str, ...]) -> str:
    """The command-line spelling of a nested option: ('edit', 'distill', 'lr') ->
    '--edit.distill.lr'."""
    return "--" + ".".join(p.replace("_", "-") for p in path)


def spelt(prefix: str, name: str) -> str:
    """An option's flag under a prefix: ('--edit.distill', 'lr') -> '--edit.distill.lr';
    ('', 'max_steps') -> '--max-steps' (a config whose prefix the command omits)."""
    name = name.replace("_", "-")
    return f"{prefix}.{name}" if prefix else f"--{name}"


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def at_least(minimum: int, default: Any = None) -> Any:
    """An option that means nothing below ``minimum`` (``max_width: int | None =
    at_least(8)``): the one range check refuses smaller values with one message."""
    return dataclasses.field(default=default, metadata={"min": minimum})


def at_least_one(default: int, most: int | None = None) -> Any:
    """A count option that means nothing below 1 (``views: int = at_least_one(3)``), and
    with ``most`` nothing sensible above it (a typo of 100000 turns would run for hours)."""
    field = at_least(1, default)
    return (
        field
        if most is None
        else dataclasses.field(default=default, metadata={"min": 1, "max": most})
    )


def _check_number(name: str, value: Any, f: dataclasses.Field, where: str) -> None:
    default = _default(f)
    if not math.isfinite(value):
        raise NeoError(f"{where} must be a finite number, got {value}")
    if name == "seed":
        top = f.metadata.get("max", SEED_RANGE - 1)  # a library's own narrower range
        if not (isinstance(value, int) and 0 <= value <= top):
            span = "[0, 2^32)" if top == SEED_RANGE - 1 else f"[0, {top}]"
            raise NeoError(f"{where} must be a whole number in {span}, got {value}")
        return
    if isinstance(value, int) and abs(value) > MAX_INT:
        raise NeoError(f"{where} must be at most {MAX_INT} in size, got {value}")
    if isinstance(value, float) and abs(value) > MAX_FLOAT and name not in ("yaw", "yaw_deg"):
        raise NeoError(f"{where} must be at most {MAX_FLOAT:g} in size, got {value:g}")
    if name in OWN_BOUNDS:
        return
    if "min" in f.metadata and value < f.metadata["min"]:
        raise NeoError(f"{where} must be >= {f.metadata['min']}, got {value}")
    if "max" in f.metadata and value > f.metadata["max"]:
        raise NeoError(f"{where} must be <= {f.metadata['max']}, got {value}")
    check_bound(name, value, where)
    if name in POSITIVE and value <= 0:
        raise NeoError(f"{where} must be > 0, got {value}")
    if _UNIT.search(name) and not 0 <= value <= 1:
        raise NeoError(f"{where} must be within [0, 1], got {value}")
    nonnegative = name not in SIGNED and (not _number(default) or default >= 0)
    if nonnegative and value < 0:
        raise NeoError(f"{where} must be >= 0, got {value}")


def _hints(cls: type) -> dict[str, Any]:
    try:
        return typing.get_type_hints(cls, include_extras=True)
    except Exception:  # noqa: BLE001 -- an unresolvable hint only costs the flag's prefix
        return {}


def _omits_prefix(hint: Any) -> bool:
    """A nested config whose options are spelt without its name (tyro's OmitArgPrefixes:
    ``--max-steps``, not ``--train.max-steps``)."""
    import tyro

    return any(m is tyro.conf.OmitArgPrefixes for m in getattr(hint, "__metadata__", ()))


def _unnamed(hint: Any) -> bool:
    """A nested config spelt without its own name but with its groups' (``tyro.conf.arg(
    name="")``: ``neo remove --refine.steps``, not ``--edit.refine.steps``)."""
    return any(getattr(m, "name", None) == "" for m in getattr(hint, "__metadata__", ()))


def check_options(cfg: Any, path: tuple[str, ...] = (), omit: bool = False) -> None:
    """Every numeric option of a (nested) config dataclass by the module's rules; tuples of
    numbers (translations, boxes) only finite. Raises :class:`NeoError` naming the flag.
    ``omit``: the command spells the options below here without prefixes (tyro's
    OmitArgPrefixes reaches every level under the config it marks)."""
    hints = _hints(type(cfg))
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        here = (*path, f.name)
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            below = omit or _omits_prefix(hints.get(f.name))
            unnamed = below or _unnamed(hints.get(f.name))
            check_options(value, path if unnamed else here, below)
        elif _number(value):
            _check_number(f.name, value, f, flag(here))
        elif isinstance(value, (tuple, list)):
            _check_numbers(f.name, [v for v in value if _number(v)], _default(f), flag(here))


def _check_numbers(name: str, values: list[Any], default: Any, where: str) -> None:
    """A tuple option (a size, a path of distances, a direction): finite, of a sane size,
    never negative where no default entry is, and a direction not the zero vector."""
    for item in values:
        if not math.isfinite(item) or abs(item) > MAX_FLOAT:
            raise NeoError(f"{where} must be finite numbers of at most {MAX_FLOAT:g}, got {item}")
    defaults = [d for d in default if _number(d)] if isinstance(default, (tuple, list)) else []
    if defaults and name not in SIGNED and min(defaults) >= 0 and values and min(values) < 0:
        raise NeoError(f"{where} must be >= 0, got {min(values)}")
    if name in DIRECTIONS and not any(values):
        raise NeoError(f"{where} is a direction: give a non-zero vector, e.g. 0 0 1")
