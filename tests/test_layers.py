"""Imports run one way through the package's folders (docs/architecture.md): none reaches a folder to its right."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "physdyn"
# The data flow, left to right; folders at the same place may import each other (test_structure.py keeps them
# from importing each other in a circle). config/ is used by every folder and imports none of them, like the
# package's top-level modules (registry, errors, files, write_lock), which any folder may import.
FLOW = {"config": -1, "geometry": 0, "sim": 1, "data": 2, "models": 3, "eval": 4, "pipeline": 4, "predict": 5, "viz": 5,
        "experiments": 5, "plan": 6, "cli": 7}


def imported_modules(path: Path) -> list[tuple[int, str]]:
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module))
        elif isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
    return found


def test_no_folder_imports_one_to_its_right():
    upward = []
    for folder, place in FLOW.items():
        for path in sorted((PACKAGE / folder).rglob("*.py")):
            for line, module in imported_modules(path):
                parts = module.split(".")
                if parts[0] == "physdyn" and len(parts) > 1 and FLOW.get(parts[1], -1) > place:
                    upward.append(f"{path.relative_to(PACKAGE.parent)}:{line} imports {module}")
    assert not upward, "\n".join(upward)
    assert set(FLOW) <= {p.name for p in PACKAGE.iterdir() if p.is_dir()}  # every folder named still exists
