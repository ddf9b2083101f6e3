"""MkDocs hook: the CLI reference page is generated from the argument parsers.

A page that holds the line ``<!-- cli-reference -->`` gets, in its place, one section per command
of :data:`rfmitsuba.cli.COMMANDS` with that command's ``--help`` text, so the reference cannot
drift from the parsers.
"""
from __future__ import annotations

import argparse

MARKER = "<!-- cli-reference -->"


def cli_reference() -> str:
    """Markdown: one section per command (``rfmitsuba COMMAND --help``) and its sub-commands."""
    from rfmitsuba.cli import COMMANDS, build_parser

    parser = build_parser()
    subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    out = ["## `rfmitsuba`", "", "```text", parser.format_help().rstrip(), "```", ""]
    for name in COMMANDS:
        p = subs.choices[name]
        out += [f"## `rfmitsuba {name}`", "", "```text", p.format_help().rstrip(), "```", ""]
        inner = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
        for action in inner:
            for sub_name, sp in action.choices.items():
                out += [f"### `rfmitsuba {name} {sub_name}`", "", "```text", sp.format_help().rstrip(), "```", ""]
    return "\n".join(out)


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER in markdown:
        return markdown.replace(MARKER, cli_reference())
    return markdown
