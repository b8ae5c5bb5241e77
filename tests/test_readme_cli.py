"""The README's command line stays true: every command the parser has is in its table, and every
``--flag`` the README names belongs to some command (a renamed or removed option fails here)."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from reflexarm.cli import build_parser

README = Path(__file__).resolve().parents[1] / "README.md"
#: Lines of the README about other tools (building, installing), whose flags are not reflexarm's.
FOREIGN_LINE = re.compile(r"cmake|pip install")


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def commands_and_flags() -> tuple[set[str], set[str]]:
    """Every command path (``simulate link-collision``) and every option string of the parser tree."""
    commands: set[str] = set()
    flags: set[str] = set()

    def walk(parser: argparse.ArgumentParser, path: tuple[str, ...]) -> None:
        flags.update(s for a in parser._actions for s in a.option_strings)
        subs = _subparsers(parser)
        if path and not subs:
            commands.add(" ".join(path))
        for name, sub in subs.items():
            walk(sub, (*path, name))

    walk(build_parser(), ())
    return commands, flags


def command_table() -> str:
    text = README.read_text()
    start = text.index("## The command line")
    return text[start : text.index("\n## ", start + 1)]


@pytest.mark.parametrize("command", sorted(commands_and_flags()[0]))
def test_every_command_has_a_row_in_the_readme_table(command):
    rows = [line for line in command_table().splitlines() if line.startswith("| `reflexarm ")]
    assert any(row.startswith(f"| `reflexarm {command}") for row in rows), f"no README row for 'reflexarm {command}'"


def test_every_flag_the_readme_names_exists():
    _, flags = commands_and_flags()
    lines = [line for line in README.read_text().splitlines() if not FOREIGN_LINE.search(line)]
    named = {flag for line in lines for flag in re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", line)}
    assert "--robot" in named and "--recorded-residual" in named  # the scan sees the README's commands
    unknown = sorted(named - flags)
    assert not unknown, f"README names options no command has: {unknown}"
