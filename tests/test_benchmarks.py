"""benchmarks/ stays research beside the library: no script edits ``sys.path``, none reassigns an attribute of
physdyn (a module, or an object imported from it), the studies import what they share by package name, and
every script is named by a page of the docs, which records what it measured. Static: nothing here runs a
benchmark."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
SHARED = BENCHMARKS / "studies" / "common.py"  # the code the studies share


def benchmark_files() -> list[Path]:
    return sorted(p for p in BENCHMARKS.rglob("*.py") if "__pycache__" not in p.parts)


def sys_path_edits(source: str) -> list[int]:
    """Lines that name ``sys.path``, in code or in a command a docstring gives."""
    return [n for n, line in enumerate(source.splitlines(), 1) if re.search(r"\bsys\s*\.\s*path\b", line)]


def physdyn_names(tree: ast.AST) -> set[str]:
    """The names a module binds to physdyn or to something imported from it."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "physdyn" or alias.name.startswith("physdyn."):
                    names.add(alias.asname or alias.name.split(".")[0])
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and (
                node.module == "physdyn" or node.module.startswith("physdyn.")):
            names.update(alias.asname or alias.name for alias in node.names)
    return names


def _root_name(node: ast.AST) -> str | None:
    while isinstance(node, (ast.Attribute, ast.Subscript)):
        node = node.value
    return node.id if isinstance(node, ast.Name) else None


def _targets(node: ast.AST) -> list[ast.AST]:
    if isinstance(node, ast.Assign):
        targets = list(node.targets)
    elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
        targets = [node.target]
    else:
        return []
    flat = []
    while targets:
        target = targets.pop()
        if isinstance(target, (ast.Tuple, ast.List)):
            targets.extend(target.elts)
        elif isinstance(target, ast.Starred):
            targets.append(target.value)
        else:
            flat.append(target)
    return flat


def physdyn_reassignments(source: str) -> list[int]:
    """Lines that assign an attribute of physdyn (``module.function = ...``, ``Class.method = ...``, an
    augmented assignment) or call ``setattr`` on it: a library function replaced for the run."""
    tree = ast.parse(source)
    names = physdyn_names(tree)
    hits = set()
    for node in ast.walk(tree):
        for target in _targets(node):
            if isinstance(target, ast.Attribute) and _root_name(target) in names:
                hits.add(node.lineno)
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("setattr", "delattr")
                and node.args and _root_name(node.args[0]) in names):
            hits.add(node.lineno)
    return sorted(hits)


def bare_sibling_imports(source: str, siblings: set[str]) -> list[int]:
    """Lines that import a file of benchmarks/ by its bare name: that needs its folder on ``sys.path``. A
    study imports ``benchmarks.NAME`` or ``benchmarks.studies.NAME`` and is run with ``python -m``."""
    hits = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            modules = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            modules = [node.module]
        else:
            continue
        if any(module.split(".")[0] in siblings for module in modules):
            hits.append(node.lineno)
    return hits


def is_helper_module(path: Path, sources: dict[Path, str]) -> bool:
    """A module another benchmark imports and that runs nothing of its own (``frontier_sets.py`` for
    ``frontier.py``): it needs no page of its own."""
    if path.name == "__init__.py" or path == SHARED:
        return True
    if '__name__ == "__main__"' in sources[path]:
        return False
    pattern = re.compile(rf"^\s*(?:from|import)\s+(?:\.|benchmarks\.)?{re.escape(path.stem)}\b", re.M)
    return any(pattern.search(text) for other, text in sources.items() if other != path)


def cited(path: Path, docs_text: str) -> bool:
    """Whether the docs name the script: by its path (``benchmarks/studies/NAME.py``) or as a module
    (``python -m benchmarks.studies.NAME``)."""
    relative = path.relative_to(ROOT)
    module = ".".join(relative.with_suffix("").parts)
    return (re.search(rf"(?<![\w/]){re.escape(relative.as_posix())}\b", docs_text) is not None
            or re.search(rf"(?<![\w.]){re.escape(module)}(?![\w])", docs_text) is not None)


def docs_text() -> str:
    pages = sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]
    return "\n".join(page.read_text(encoding="utf-8") for page in pages)


@pytest.fixture(scope="module")
def sources() -> dict[Path, str]:
    return {path: path.read_text(encoding="utf-8") for path in benchmark_files()}


def test_no_benchmark_edits_sys_path(sources):
    hits = [f"{path.relative_to(ROOT)}:{line}" for path, text in sources.items() for line in sys_path_edits(text)]
    assert not hits, ("these edit sys.path; a script of benchmarks/ imports its siblings as Python finds them "
                      f"(its own folder), a study by package name, run with python -m benchmarks.studies.NAME: {hits}")


def test_no_benchmark_replaces_a_library_function(sources):
    hits = [f"{path.relative_to(ROOT)}:{line}" for path, text in sources.items() for line in physdyn_reassignments(text)]
    assert not hits, ("these reassign an attribute of physdyn for the run; use a public option, or leave the "
                      f"question out of benchmarks/: {hits}")


def test_studies_import_shared_code_by_package_name(sources):
    siblings = {p.stem for p in benchmark_files() if p.name != "__init__.py"}
    studies = {path: text for path, text in sources.items() if path.parent == BENCHMARKS / "studies"}
    hits = [f"{path.relative_to(ROOT)}:{line}" for path, text in studies.items()
            for line in bare_sibling_imports(text, siblings)]
    assert not hits, f"import these as benchmarks.NAME or benchmarks.studies.common: {hits}"


def test_every_benchmark_script_is_cited_by_the_docs(sources):
    text = docs_text()
    uncited = [str(path.relative_to(ROOT)) for path in sources
               if not is_helper_module(path, sources) and not cited(path, text)]
    assert not uncited, ("no page of docs/ or README.md names these; cite each with its command where its "
                         f"result is recorded, or remove it and say in the page where it last ran: {uncited}")


PATCHES = [
    "import physdyn.models.priors as pri\npri.contact_geometry = lambda p: p\n",
    "from physdyn.models import outcome_correction as oc\noc.INPUTS, oc.MIRROR_INPUTS = 14, None\n",
    "from physdyn.predict import planner\nplanner.BulletRollout.__call__ = print\n",
    "import physdyn\nphysdyn.eval.rollout.rollout = None\n",
    "from physdyn.models import priors\npriors.SUPPORT_DEPTH += 0.001\n",
    "import physdyn.predict.predictor as p\nsetattr(p.Predictor, 'predict_many', print)\n",
    "from physdyn.predict.predictor import Predictor\nPredictor.predict = print\n",
    "from physdyn.sim import cloud_body\ncloud_body._SHARED['x'] = 1\ncloud_body._SHARED = {}\n",
]
FINE = [
    "import physdyn.models.priors as pri\nSHIPPED = pri.contact_geometry\n",
    "from physdyn import load_predictor\npredictor = load_predictor('fast')\nargs = object()\n",
    "import argparse\nargs = argparse.Namespace()\nargs.out = 1\nsetattr(args, 'x', 2)\n",
    "class Out:\n    pass\nout = Out()\nout.ms = {}\n",
]


@pytest.mark.parametrize("source", PATCHES)
def test_reassignment_detector_catches(source):
    assert physdyn_reassignments(source), source


@pytest.mark.parametrize("source", FINE)
def test_reassignment_detector_passes(source):
    assert not physdyn_reassignments(source), source


def test_sys_path_detector():
    assert sys_path_edits("import sys\nsys.path.insert(0, 'benchmarks')\n") == [2]
    assert sys_path_edits('"""python -c "import sys; sys.path.append(\'x\')""""\n') == [1]
    assert sys_path_edits("import sys\nprint(sys.argv)\n") == []


def test_sibling_import_detector():
    siblings = {"frontier", "frontier_sets", "common"}
    assert bare_sibling_imports("import frontier as fr\nfrom frontier_sets import truth_store\n", siblings) == [1, 2]
    assert bare_sibling_imports("from benchmarks import frontier as fr\nfrom benchmarks.studies.common import x\n"
                                "import numpy\n", siblings) == []


def test_citation_matcher():
    path = BENCHMARKS / "studies" / "spin_decel.py"
    assert cited(path, "run `python -m benchmarks.studies.spin_decel STORE`")
    assert cited(path, "see benchmarks/studies/spin_decel.py")
    assert not cited(path, "`python -m benchmarks.studies.spin_decel_v2`")
    assert not cited(path, "spin_decel.py alone")
    assert cited(BENCHMARKS / "frontier.py", "`python benchmarks/frontier.py --quick`")
    assert not cited(BENCHMARKS / "frontier.py", "`python benchmarks/frontier_sets.py`")
