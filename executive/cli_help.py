"""``--help`` that names every default (issue 18).

An option's help states its range itself ("Hz, 10 to 50"); its default is added here,
``(default: X)``, unless the help already says what the default is (``default`` in its
text: "default: the scenario's duration", "default 50"). Flags (store_true and the like)
default to off and say nothing more. Applied once to the whole parser in
:func:`executive.cli.build_parser`, so a subcommand added by any module gets it.
"""

from __future__ import annotations

import argparse


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """:class:`argparse.ArgumentDefaultsHelpFormatter` without "(default: None)",
    "(default: False)" or a second default where the help names one already."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help
        if text is None or text is argparse.SUPPRESS or "default" in text.lower():
            return text
        if action.default is None or action.default is argparse.SUPPRESS:
            return text
        if action.nargs == 0 and not isinstance(action, argparse.BooleanOptionalAction):
            return text  # a flag: off unless given
        if not action.option_strings and action.nargs not in ("?", "*"):
            return text  # a required positional argument has no default
        return f"{text} (default: %(default)s)"


def _parsers(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """``parser`` and every subcommand's parser below it."""
    found = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in dict.fromkeys(action.choices.values()):  # aliases share a parser
                found += _parsers(child)
    return found


def show_defaults(parser: argparse.ArgumentParser) -> None:
    """Every ``--help`` of ``parser`` and its subcommands names the defaults."""
    for each in _parsers(parser):
        each.formatter_class = DefaultsHelpFormatter


def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The subcommands of ``parser`` by name (for tests and docs)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}
