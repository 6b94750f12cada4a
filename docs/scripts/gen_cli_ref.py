"""The CLI reference pages, written from `physdyn`'s own argparse parser when the site is built.

mkdocs-gen-files runs this script during `mkdocs build`: it writes ``reference/cli/index.md`` (every command,
one line each, and ``physdyn --help``), one page per subcommand (its description, then its ``--help``; a
nested subcommand such as ``physdyn data info`` gets a section of its parent's page) and
``reference/cli/SUMMARY.md``, the section's navigation for mkdocs-literate-nav. Nothing is stored in docs/, so
the pages cannot drift from the parser. ``pages()`` is what the tests import.
"""

from __future__ import annotations

import argparse
import html
import os
import re
from contextlib import contextmanager
from typing import Iterator

OUT_DIR = "reference/cli"
# The width argparse wraps help at: fixed, so a page does not depend on the terminal that built it.
COLUMNS = 90


def subcommands(parser: argparse.ArgumentParser) -> list[tuple[str, str, argparse.ArgumentParser]]:
    """``(name, one-line help, parser)`` for each subcommand of ``parser``, in ``--help`` order."""
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            seen: set[int] = set()
            for name, sub in action.choices.items():
                if id(sub) in seen:  # an alias of a command listed already
                    continue
                seen.add(id(sub))
                found.append((name, helps.get(name, ""), sub))
    return found


@contextmanager
def _fixed_terminal() -> Iterator[None]:
    keys = ("COLUMNS", "NO_COLOR", "PYTHON_COLORS")
    saved = {k: os.environ.get(k) for k in keys}
    os.environ.update(COLUMNS=str(COLUMNS), NO_COLOR="1", PYTHON_COLORS="0")
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _prose(text: str) -> str:
    """``text`` as Markdown prose: code spans kept, angle brackets, asterisks and underscores outside them
    escaped, so "<trial>.npz" or "trial_NNN" print as written."""
    parts = re.split(r"(`[^`]*`)", " ".join((text or "").split()))
    out = []
    for part in parts:
        if part.startswith("`") and part.endswith("`") and len(part) > 1:
            out.append(part)
        else:
            out.append(html.escape(part, quote=False).replace("*", r"\*").replace("_", r"\_"))
    return "".join(out)


def _help_block(parser: argparse.ArgumentParser) -> str:
    with _fixed_terminal():
        text = parser.format_help().rstrip()
    return f"```text\n{text}\n```\n"


def _section(parser: argparse.ArgumentParser, level: int, one_line: str = "") -> str:
    lines = [f"{'#' * level} {parser.prog}", ""]
    description = parser.description or one_line
    if description:
        lines += [_prose(description), ""]
    lines.append(_help_block(parser))
    for name, help_, sub in subcommands(parser):
        lines.append(_section(sub, level + 1, help_))
    return "\n".join(lines)


def _page_name(command: str) -> str:
    return f"{command}.md"


def pages(parser: argparse.ArgumentParser | None = None) -> dict[str, str]:
    """Every generated page: its path under docs/ -> its Markdown."""
    if parser is None:
        from physdyn.cli import build_parser

        parser = build_parser()
    commands = subcommands(parser)
    out: dict[str, str] = {}
    rows = [
        "# Command-line reference",
        "",
        "Every `physdyn` command, with the `--help` it prints. These pages are written from the command's own "
        "parser each time the site is built. `physdyn COMMAND --help` prints the same in a terminal.",
        "",
        "| Command | What it does |",
        "|---|---|",
    ]
    for name, help_, _ in commands:
        rows.append(f"| [`physdyn {name}`]({_page_name(name)}) | {_prose(help_)} |")
    rows += ["", "## physdyn", ""]
    if parser.description:
        rows += [_prose(parser.description), ""]
    rows.append(_help_block(parser))
    out[f"{OUT_DIR}/index.md"] = "\n".join(rows)
    for name, help_, sub in commands:
        out[f"{OUT_DIR}/{_page_name(name)}"] = _section(sub, 1, help_)
    summary = ["* [Overview](index.md)"] + [f"* [{name}]({_page_name(name)})" for name, _, _ in commands]
    out[f"{OUT_DIR}/SUMMARY.md"] = "\n".join(summary) + "\n"
    return out


def write_pages() -> None:
    import mkdocs_gen_files
    from mkdocs.structure.files import InclusionLevel

    for path, text in pages().items():
        with mkdocs_gen_files.open(path, "w") as f:
            f.write(text)
    # SUMMARY.md is the section's nav for literate-nav, which still reads it; not a page of the site
    summary = mkdocs_gen_files.FilesEditor.current().files.get_file_from_path(f"{OUT_DIR}/SUMMARY.md")
    if summary is not None:
        summary.inclusion = InclusionLevel.EXCLUDED


if __name__ == "<run_path>":  # run by mkdocs-gen-files during the build
    write_pages()
elif __name__ == "__main__":  # a look at what would be written
    for path, text in pages().items():
        print(f"{path}: {len(text.splitlines())} lines")
