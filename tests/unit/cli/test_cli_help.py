"""Every `bench` argument says what it is and, when it has one, its default (issue 19)."""

from __future__ import annotations

import argparse

import pytest

from bench.cli.main import build_parser

_NO_DEFAULT = (None, False, "", [], argparse.SUPPRESS)


def _arguments(parser: argparse.ArgumentParser, path: tuple[str, ...]):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _arguments(sub, (*path, name))
        elif not isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
            yield path, action


ARGUMENTS = list(_arguments(build_parser(load_all=True), ("bench",)))


def _label(item) -> str:
    path, action = item
    return " ".join(path) + " " + ("/".join(action.option_strings) or action.dest)


@pytest.mark.parametrize("item", ARGUMENTS, ids=_label)
def test_every_argument_has_help_that_states_its_default(item):
    _, action = item
    if action.help == argparse.SUPPRESS:
        return                        # hidden on purpose (test-only options such as `search --groups`)
    assert action.help, "no help text"
    default = action.default
    if default not in _NO_DEFAULT and not isinstance(action, (argparse._StoreTrueAction, argparse._StoreConstAction)):
        assert "default" in action.help, f"default {default!r} not stated in {action.help!r}"


def _subparsers(parser: argparse.ArgumentParser) -> argparse._SubParsersAction:
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))


def test_the_schedules_help_names_all_its_subcommands():
    """It said "list, show and validate" while analyze, search and recommend were there too."""
    commands = _subparsers(build_parser(load_all=True))
    schedules = commands.choices["schedules"]
    names = list(_subparsers(schedules).choices)
    assert names == ["list", "show", "validate", "analyze", "search", "recommend"]
    one_line = next(a.help for a in commands._choices_actions if a.dest == "schedules")
    for text in (schedules.description, one_line):
        assert all(name in text for name in names), text
