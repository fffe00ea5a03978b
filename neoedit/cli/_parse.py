"""Parsing ``neo``'s arguments with tyro, with its error boxes condensed to an ``error:``
line, at most five suggestions and where to find the help (tyro's own box can list every
similar option of every verb: thousands of characters for one typo)."""

from __future__ import annotations

import contextlib
import difflib
import io
import re
import sys
from collections.abc import Sequence
from typing import Any, get_args

import tyro

MAX_SUGGESTIONS = 5
_OPTION = re.compile(r"(?<![\w-])--[a-z0-9][a-z0-9.-]*[a-z0-9]")
_HELP = re.compile(r"(neo\b[\w .-]*?--help)")
_OWNER = re.compile(r"^in (neo\b[\w .-]*?) --help$")
_NOISE = re.compile(r" \(applied to [^)]*\)|Arguments are applied to the directly preceding.*$")
_MARKUP = re.compile(r"\[/?(?:bold|dim|italic|underline|red|green|yellow|cyan|magenta|blue)\]")
"""Style tags tyro leaves in some messages' text (``[bold]FLOAT FLOAT FLOAT[/bold]``)."""
_BOOL_WORD = re.compile(r"^Unrecognized.*options: (True|False)( (True|False))*$")
"""A value after an on/off flag (``--field.closed-bottom True``) that tyro does not take."""
GROUPS = ("sim", "import")
"""Verbs with verbs of their own (neo sim scene, neo import colmap)."""


def verbs(commands: Any) -> set[str]:
    """The verb names of a Union of ``tyro.conf.subcommand``-annotated commands."""
    names = set()
    for option in get_args(commands):
        for marker in getattr(option, "__metadata__", ()):
            name = getattr(marker, "name", None)
            if isinstance(name, str):
                names.add(name)
    return names


def verb_of(args: list[str], known: set[str]) -> str:
    """'neo move' for ['move', 'scene', 'mug', '--out', 'x'] (the command whose help to show;
    'neo' when the first word is no verb)."""
    if not args or args[0] not in known:
        return "neo"
    words: list[str] = []
    for a in args:
        if a.startswith("-") or len(words) == (2 if words[:1] and words[0] in GROUPS else 1):
            break
        words.append(a)
    return " ".join(["neo", *words])


def _rows(text: str) -> list[str]:
    """The lines inside tyro's box: drawn with box characters on a UTF-8 terminal, else a
    title line and a dashed rule above indented lines (the title is dropped either way)."""
    rows = []
    for line in text.splitlines():
        s = line.strip()
        if s.startswith(("╭", "╰")):
            continue
        rows.append(s.strip("│").strip())
    if "╭" not in text:
        while rows and not rows[0]:
            rows.pop(0)
        if len(rows) > 1 and _is_rule(rows[1]):
            rows = rows[2:]
    return rows


def _is_rule(row: str) -> bool:
    return len(row) >= 3 and set(row) <= {"─", "-"}


def _sections(rows: list[str]) -> list[list[str]]:
    sections: list[list[str]] = [[]]
    for r in rows:
        if _is_rule(r):
            sections.append([])
        elif r:
            sections[-1].append(r)
    return [s for s in sections if s]


def condense(text: str, verb: str = "neo", options: Sequence[str] = ()) -> str:
    """tyro's error box -> 'error: ...' plus a suggestion line and a help line (the text
    as it is when it is not a box). ``options``: every option of ``verb`` (when known), so
    that its own option of the same name comes first and suggestions of no verb are
    dropped."""
    sections = _sections(_rows(text))
    if not sections:
        return text.strip()
    lines = ["error: " + _MARKUP.sub("", _NOISE.sub("", " ".join(sections[0]))).strip()]
    count, tup = _COUNT.search(lines[0]), _TUPLE.search(lines[0])
    if count:  # tyro lists every type it tried; the user needs the count
        option, got, want = count.groups()
        lines[0] = f"error: {option} takes {want} values, got {got}"
    elif tup:
        kinds = tup.group(2).split(", ")
        what = "numbers" if "float" in kinds else "whole numbers"
        lines[0] = f"error: {tup.group(1)} takes {len(kinds)} {what}"
    suggestions: list[str] = []
    help_hint = None
    for section in sections[1:]:
        joined = " ".join(section)
        if section[0].startswith(("Perhaps you meant", "Arguments similar to")):
            suggestions += [s for s in _suggested(section[1:], verb) if s not in suggestions]
        found = _HELP.search(joined)
        if found and "helptext" in joined:
            help_hint = found.group(1)
    if options:
        suggestions = _ranked(sections[0], suggestions, options)
    bad_value = _BAD_VALUE.search(" ".join(sections[0]))
    missing = None if bad_value else _absent(sections[0], suggestions, verb)
    if bad_value:  # the option exists: its value is what is wrong, no other name helps
        if bad_value.group(2):
            lines.append(f"  {bad_value.group(1)} takes {_KINDS[bad_value.group(2)]}")
    elif not suggestions and _BOOL_WORD.search(" ".join(sections[0])):
        lines.append(
            "  an on/off option takes no True/False after it: write --NAME to turn it on, "
            "--no-NAME to turn it off"
        )
    elif missing:
        lines.append(f"  {verb} has no {missing}" + INSTEAD.get((verb, missing), ""))
    elif suggestions:
        lines.append("  did you mean: " + ", ".join(suggestions[:MAX_SUGGESTIONS]))
    if help_hint in (None, "neo --help"):
        help_hint = f"{verb} --help"
    lines.append(f"  every option: {help_hint}")
    return "\n".join(lines)


_COUNT = re.compile(
    r"Error parsing (--[\w.-]+):.*input length (\d+) did not match expected argument count (\d+)"
)
"""tyro's message for a tuple option given too few or too many values."""
_TUPLE = re.compile(
    r"Error parsing (--[\w.-]+):.*Could not parse arguments .* into tuple type "
    r"tuple\[((?:float|int)(?:, (?:float|int))*)\]"
)
"""tyro's message for a tuple option whose values are not all numbers."""
_BAD_VALUE = re.compile(
    r"Error parsing (--[\w.-]+):(?: (invalid literal for int|could not convert string to float))?"
)
"""tyro's message for a value its option's type cannot read (group 2: which type)."""
_KINDS = {
    "invalid literal for int": "a whole number (e.g. 3; not 2.5 or 1e20)",
    "could not convert string to float": "a number (e.g. 0.01 or 1e-3)",
}


def _ranked(first: list[str], suggestions: list[str], options: Sequence[str]) -> list[str]:
    """The verb's own options named like a typed one (``--no-inpaint`` ->
    ``--edit.remove.no-inpaint``) first, then tyro's suggestions that are the verb's or
    named with their verb; tyro's others (options of no verb of this spelling) dropped."""
    typed = [w.rstrip(",") for w in " ".join(first).split() if w.startswith("--")]
    tails = {w.removeprefix("--").split("=")[0] for w in typed}
    same = [o for o in options if any(o == f"--{t}" or o.endswith(f".{t}") for t in tails)]
    last = {o: o.removeprefix("--").rsplit(".", 1)[-1] for o in options}
    close = {m for t in tails for m in difflib.get_close_matches(t, set(last.values()), 3, 0.8)}
    same += [o for o in options if last[o] in close and o not in same]
    known = set(options)
    kept = [s for s in suggestions if s.split()[0] in known or "an option of" in s]
    return list(dict.fromkeys([*same, *kept]))


def verb_options(commands: Any, verb: str) -> list[str]:
    """Every option spelling of ``verb`` ('neo move'), read from its help (an error path
    only: rendering the help costs a few tenths of a second); [] for group verbs."""
    name = verb.removeprefix("neo").strip()
    for option in get_args(commands):
        markers = [getattr(m, "name", None) for m in getattr(option, "__metadata__", ())]
        inner = get_args(option)
        if name not in markers or not inner or get_args(inner[0]):
            continue
        shown = io.StringIO()
        with contextlib.redirect_stdout(shown), contextlib.redirect_stderr(io.StringIO()):
            try:
                tyro.cli(inner[0], prog=verb, args=["--help"])
            except SystemExit:
                pass
        return list(dict.fromkeys(_OPTION.findall(shown.getvalue())))
    return []


INSTEAD = {
    ("neo train", "--overwrite"): (
        ": it never replaces a trained scene; give a new --out, or --resume to train it on"
    ),
}
"""What to do instead of an option a verb does not have (keyed by verb and option)."""


def _absent(first: list[str], suggestions: list[str], verb: str) -> str | None:
    """The option the user typed when the only match tyro found is that same option of
    another verb (``neo train --overwrite``: 'did you mean --overwrite' would send the user
    round in a circle); None otherwise."""
    typed = {w for w in " ".join(first).split() if w.startswith("--")}
    exact = [s.split()[0] for s in suggestions if s.split()[0] in typed and "an option of" in s]
    if verb == "neo" or not exact or any("an option of" not in s for s in suggestions):
        return None
    return exact[0]


_CHOICES = re.compile(r"\{[^}]*\}")
"""A metavar's choices ('{small,standard}', '{None}|PATH'), lower case allowed."""


def _is_option_row(row: str) -> bool:
    """A row that names options ('--out PATH', '--a, --no-a', '--scenes [STR [STR ...]]'),
    not a line of their help text that happens to start with one ('--no-inpaint, the
    DFF-style baseline'): after the first option, only options and metavars (upper case,
    brackets, choices in braces)."""
    words = row.split()
    if not words or not words[0].startswith("-"):
        return False
    rest = [_CHOICES.sub("", w) for w in words[1:] if not w.startswith("-")]
    return not any(c.islower() for w in rest for c in w)


def _suggested(rows: list[str], verb: str) -> list[str]:
    """The options tyro suggests, each followed by the row naming the command it belongs
    to ('in neo bench --help'); an option of another command than ``verb`` is named with
    it ('--scenes (an option of neo bench)'), the options of ``verb`` come first."""
    options: list[tuple[str, str | None]] = []
    for row in rows:
        if _is_option_row(row):
            options.append((row.split()[0].rstrip(","), None))
        owner = _OWNER.match(row)
        if owner and options and options[-1][1] is None:
            options[-1] = (options[-1][0], owner.group(1))
    own = [w for w, cmd in options if cmd in (None, verb) or verb == "neo"]
    other = [f"{w} (an option of {cmd})" for w, cmd in options if w not in own]
    return [*own, *other]


def parse(commands: Any, args: list[str], description: str) -> Any:
    """The parsed command; a parse error prints the condensed message on stderr and exits 2
    (``--help`` prints tyro's full help and exits 0; anything else tyro says is passed on)."""
    captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(captured):
            return tyro.cli(commands, prog="neo", args=args, description=description)
    except SystemExit as e:
        if e.code not in (0, None) and captured.getvalue():
            verb = verb_of(args, verbs(commands))
            text = condense(captured.getvalue(), verb, verb_options(commands, verb))
            print(text, file=sys.stderr)
            captured = io.StringIO()  # said, condensed
        raise
    finally:
        sys.stderr.write(captured.getvalue())
