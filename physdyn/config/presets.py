"""Presets: the repository's configs/, shipped inside the package (physdyn/presets links to it), so
`--config quickstart` and `configs/experiment/quickstart.yaml` work after a plain `pip install` too."""

from __future__ import annotations

import re
from pathlib import Path

from physdyn.errors import ConfigError

PRESETS = Path(__file__).resolve().parents[1] / "presets"
PRESET_KINDS = ("data", "experiment", "model", "trainer", "reproduce")


def list_presets(kind: str | None = None) -> dict[str, list[tuple[str, str]]]:
    """kind -> [(name, the file's first comment line)] of the shipped presets."""
    out: dict[str, list[tuple[str, str]]] = {}
    for k in PRESET_KINDS if kind is None else (kind,):
        entries = []
        for path in sorted((PRESETS / k).glob("*.yaml")):
            entries.append((path.stem, _summary(path)))
        out[k] = entries
    return out


def _summary(path: Path, width: int = 110) -> str:
    """The first sentence of the file's opening comment, cut to ``width`` characters."""
    lines = []
    for line in path.read_text().splitlines():
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("#").strip())
    text = " ".join(lines)
    sentence = re.split(r"(?<=[.:;])\s", text, maxsplit=1)[0].rstrip(".:;")
    sentence += ")" * (sentence.count("(") - sentence.count(")"))  # a cut inside brackets
    return sentence if len(sentence) <= width else sentence[: width - 3].rstrip() + "..."


def preset_path(value: str | Path, kind: str) -> Path:
    """A config file the user named: an existing path, a preset name of ``kind`` (``quickstart``), or a
    ``configs/<kind>/<name>.yaml`` path of the source tree, found among the shipped presets."""
    path = Path(value).expanduser()
    if path.is_file():
        return path
    if not path.suffix and len(path.parts) == 1:
        named = PRESETS / kind / f"{value}.yaml"
        if named.is_file():
            return named
        names = ", ".join(name for name, _ in list_presets(kind)[kind])
        raise ConfigError(f"'{value}' is neither a config file nor a {kind} preset; presets: {names} (`physdyn configs`)")
    if "configs" in path.parts:
        shipped = PRESETS.joinpath(*path.parts[len(path.parts) - path.parts[::-1].index("configs"):])
        if shipped.is_file():
            return shipped
    return path  # missing: the loader's error names it
