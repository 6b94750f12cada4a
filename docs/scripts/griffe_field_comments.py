"""A griffe extension for the config schema page: a dataclass's fields become an "Attributes" table.

physdyn's config dataclasses (``physdyn/config/``) document each field with a ``#`` comment, on its line or
on the lines just above it, which griffe does not read. For every dataclass of the modules named in
``modules`` (and their submodules), this appends a Google-style ``Attributes:`` section to the class docstring: each field with its
type, its comment and its default. mkdocs.yml loads it for mkdocstrings (``extensions:``).
"""

from __future__ import annotations

import io
import re
import tokenize
from pathlib import Path
from typing import Any

import griffe


def _comments(source: str) -> dict[int, tuple[str, bool]]:
    """line number -> (comment text, whether the line holds only the comment)."""
    found: dict[int, tuple[str, bool]] = {}
    lines = source.splitlines()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            row = tok.start[0]
            alone = not lines[row - 1][: tok.start[1]].strip()
            found[row] = (tok.string.lstrip("#").strip(), alone)
    return found


def _default(value: str) -> str:
    """A field's default as a user writes it: ``field(default_factory=X)`` becomes ``X()``, a lambda's body."""
    m = re.fullmatch(r"field\(\s*default_factory\s*=\s*(.+?)\s*\)", value, flags=re.S)
    if not m:
        return value
    factory = m.group(1)
    lam = re.fullmatch(r"lambda\s*:\s*(.+)", factory, flags=re.S)
    if lam:
        return lam.group(1)
    return {"dict": "{}", "list": "[]"}.get(factory, f"{factory}()")


def _escape(text: str) -> str:
    """Angle brackets outside code spans as text, not HTML ("runs/<name>")."""
    parts = re.split(r"(`[^`]*`)", text)
    return "".join(p if p.startswith("`") else p.replace("<", "&lt;").replace(">", "&gt;") for p in parts)


def _is_dataclass(cls: griffe.Class) -> bool:
    return any(str(d.value).split("(")[0].split(".")[-1] == "dataclass" for d in cls.decorators)


class FieldComments(griffe.Extension):
    def __init__(self, modules: list[str] | None = None) -> None:
        self.modules = tuple(modules or ())
        self._sources: dict[str, dict[int, tuple[str, bool]]] = {}

    def on_class_members(self, *, cls: griffe.Class, agent: Any = None, **kwargs: Any) -> None:
        module = cls.module.path
        if self.modules and not any(module == m or module.startswith(m + ".") for m in self.modules):
            return
        if not _is_dataclass(cls):
            return
        path = str(cls.filepath)
        if path not in self._sources:
            self._sources[path] = _comments(Path(path).read_text(encoding="utf-8"))
        comments = self._sources[path]
        rows = []
        for member in cls.members.values():
            if member.is_alias or not member.is_attribute or member.lineno is None:
                continue
            if member.docstring is not None:
                text = " ".join(member.docstring.value.split())
            else:
                above = []
                row = member.lineno - 1
                while row in comments and comments[row][1]:
                    above.insert(0, comments[row][0])
                    row -= 1
                trailing = [comments[r][0] for r in range(member.lineno, (member.endlineno or member.lineno) + 1)
                            if r in comments and not comments[r][1]]
                text = " ".join(above + trailing)
            if text and text[-1] not in ".!?:;":
                text += "."
            text = _escape(text[:1].upper() + text[1:])
            default = "" if member.value is None else _default(str(member.value))
            if default:
                text = f"{text} Default: `{default}`." if text else f"Default: `{default}`."
            annotation = f" ({member.annotation})" if member.annotation is not None else ""
            rows.append(f"    {member.name}{annotation}: {text or '-'}")
        if not rows:
            return
        body = cls.docstring.value if cls.docstring is not None else ""
        # without a summary line, a leading newline keeps the rows' indentation through inspect.cleandoc
        value = (body.rstrip() + "\n\n" if body.strip() else "\n") + "Attributes:\n" + "\n".join(rows)
        old = cls.docstring
        cls.docstring = griffe.Docstring(
            value,
            lineno=old.lineno if old is not None else cls.lineno,
            endlineno=old.endlineno if old is not None else cls.lineno,
            parent=cls,
            parser=old.parser if old is not None else getattr(agent, "docstring_parser", None),
            parser_options=old.parser_options if old is not None else getattr(agent, "docstring_options", None),
        )
