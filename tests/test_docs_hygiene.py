"""Keeps the documentation honest: no development history, no commit hashes in prose, no dead links, and
no `physdyn` command or option in the README that the CLI does not have, and no `physdyn predict` in the docs
that gives one post-push velocity without the other.

Pages and code say what a thing is and why, for a user of the package; history goes to CHANGELOG.md. The
checks read files only (no processes, no network) and take about a second. Each failure names the file, the
line, the offending text and the fix. The detectors are tested on small strings first, so that a check that
matches nothing cannot pass silently.
"""

from __future__ import annotations

import argparse
import ast
import functools
import importlib.util
import io
import re
import shlex
import tokenize
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# What is scanned for history wording and commit hashes.
SCANNED_DIRS = ("docs", "physdyn", "tests", "benchmarks", "plugins", "configs")
SCANNED_SUFFIXES = {".py", ".md", ".yaml", ".yml"}
SCANNED_TOP_FILES = ("README.md", "Makefile")
SKIPPED_PARTS = {"__pycache__", ".pytest_cache", ".git", "build", "dist", "site", ".venv"}
EXEMPT_FILES = {ROOT / "CHANGELOG.md"}  # the changelog is history

# --------------------------------------------------------------------------------------------------------------
# Detectors
# --------------------------------------------------------------------------------------------------------------

# The words this check looks for are spelt in pieces in this file, so that it holds none of them whole and
# passes the same check as every other file (and any other reader of the tree).
WORK = "ses" + "sion"  # the word for a stretch of work
TICKET = "is" + "sue"
CHECKED = "re" + "view"
FIXED = "me" + "nd"
READ_THROUGH = "read" + "-through"
_UNITS = "first|second|third|fourth|fifth|sixth|seventh|eighth|ninth"
_TEENS = "|".join(stem + "th" for stem in ("eleven", "twelf", *(f"{p}teen" for p in
                                                              ("thir", "four", "fif", "six", "seven", "eigh", "nine"))))
_TENS = "twenty|thirty|forty|fifty|sixty|seventy|eighty|ninety"
_TENTHS = "|".join(f"{tens[:-1]}ie" + "th" for tens in _TENS.split("|")) + "|hundred" + "th"
_ANY_ORDINAL = rf"(?:{_UNITS}|tenth|{_TEENS}|{_TENTHS}|(?:{_TENS})[- ](?:{_UNITS})|\d+(?:st|nd|rd|th))"

# (label, pattern, fix). Matched case-insensitively, line by line.
HISTORY_PATTERNS: list[tuple[str, re.Pattern[str], str]] = [
    ("an ordinal naming a stretch of work", re.compile(rf"\b{_ANY_ORDINAL}\s+{WORK}s?\b", re.I),
     "say what the thing is (e.g. 'the PointNet topple classifier'), not when it was made"),
    (f"the word '{WORK}' for a stretch of work", re.compile(rf"\b{WORK}s?\b", re.I),
     "say what the thing is or name the command that measured it; history goes to CHANGELOG.md"),
    ("a ticket number", re.compile(rf"\b{TICKET}s?\s*(?:#\s*)?\d+", re.I),
     "drop the ticket number and say what the thing is or why"),
    ("wording about who checked it", re.compile(rf"\b{CHECKED}(?:s|er|ers|ed|ing)?\b", re.I),
     "drop who checked it; give the command that checks it instead"),
    ("wording about what was fixed", re.compile(rf"\b{FIXED}(?:s|ed|ing)?\b", re.I),
     "say what the code does, not what was fixed"),
    (f"'{READ_THROUGH}'", re.compile(rf"\b{READ_THROUGH}s?\b", re.I),
     "drop the narrative; say what is true"),
    ("an ordinal from 'eleven-th' up", re.compile(
        rf"\b(?:{_TEENS}|{_TENTHS}|(?:{_TENS})-(?:{_UNITS}))\b", re.I),
     "say what the thing is, not which stretch of work made it"),
    ("a run name that encodes a stretch of work", re.compile(
        r"(?<!\d)\d{4}s\d{1,2}(?!\d)|(?:^|(?<=[/\s`'\"(]))s\d{1,2}[a-z]?/", re.I),
     "name the command that makes the run (e.g. `python benchmarks/frontier.py`) instead of its folder"),
]

# A cheap first pass: a line none of these occur in holds none of the patterns above.
HISTORY_KEYWORDS = (WORK, TICKET, CHECKED, FIXED, READ_THROUGH, *_TEENS.split("|"), *_TENTHS.split("|"),
                    *(f"{tens}-" for tens in _TENS.split("|")))
RUN_NAME_HINT = re.compile(r"\d{4}s\d|s\d\d?[a-z]?/")


def may_hold_history(text: str) -> bool:
    """False where none of HISTORY_PATTERNS can match (substring tests: fast on a whole file)."""
    low = text.lower()
    return any(word in low for word in HISTORY_KEYWORDS) or bool(RUN_NAME_HINT.search(low))


# Lines where the word for a stretch of work is a technical term, matched exactly (the identifier, not the file).
WORK_ALLOWED = [
    re.compile(rf"""scope\s*=\s*["']{WORK}["']"""),  # pytest's fixture scope
]

HASH = re.compile(r"(?<![\w/.-])(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}(?![\w-])")
# A hash of digits only reads as a number unless a word next to it says it is a commit.
DIGITS = re.compile(r"(?<![\w/.-])\d{7,40}(?![\w-])")
COMMIT_BEFORE = re.compile(r"\b(?:commits?|main|master|head|branch|sha|revision|rev|at|on)\W{0,3}$", re.I)
COMMIT_AFTER = re.compile(r"^\W{0,3}commits?\b", re.I)


def history_hits(line: str) -> list[tuple[str, str, str]]:
    """(label, matched text, fix) for each piece of development-history wording in one line."""
    if not may_hold_history(line):
        return []
    hits = []
    seen_spans: list[tuple[int, int]] = []
    for label, pattern, fix in HISTORY_PATTERNS:
        for match in pattern.finditer(line):
            if any(a <= match.start() < b for a, b in seen_spans):
                continue  # already reported by a more specific pattern
            if WORK in label and any(allow.search(line) for allow in WORK_ALLOWED):
                masked = line
                for allow in WORK_ALLOWED:
                    masked = allow.sub(lambda m: "_" * len(m.group()), masked)
                if not pattern.search(masked):
                    continue
            seen_spans.append(match.span())
            hits.append((label, match.group(), fix))
    return hits


def hash_hits(text: str) -> list[str]:
    """Tokens that look like a commit hash (7-40 lowercase hex characters with a digit and a letter)."""
    found = [(m.start(), m.group()) for m in HASH.finditer(text)]
    found += [(m.start(), m.group()) for m in DIGITS.finditer(text)
              if COMMIT_BEFORE.search(text[max(0, m.start() - 20):m.start()])
              or COMMIT_AFTER.search(text[m.end():m.end() + 12])]
    return [token for _, token in sorted(found)]


def python_prose(source: str) -> list[tuple[int, str]]:
    """(line number, text) of every comment and docstring in a Python source."""
    out: list[tuple[int, str]] = []
    try:
        for tok in tokenize.generate_tokens(io.StringIO(source).readline):
            if tok.type == tokenize.COMMENT:
                out.append((tok.start[0], tok.string))
    except (tokenize.TokenError, IndentationError, SyntaxError):
        pass
    try:
        tree = ast.parse(source)
    except SyntaxError:
        return out
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if (isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
                    and isinstance(first.value.value, str)):
                for i, text in enumerate(first.value.value.splitlines()):
                    out.append((first.lineno + i, text))
    return out


def scanned_files() -> list[Path]:
    files = [ROOT / name for name in SCANNED_TOP_FILES if (ROOT / name).is_file()]
    for folder in SCANNED_DIRS:
        for path in sorted((ROOT / folder).rglob("*")):
            if (path.is_file() and path.suffix in SCANNED_SUFFIXES
                    and not SKIPPED_PARTS.intersection(path.relative_to(ROOT).parts)
                    and not any(p.endswith(".egg-info") for p in path.parts)):
                files.append(path)
    return [f for f in files if f.resolve() not in EXEMPT_FILES]


@functools.cache
def _read(path: Path) -> str:
    return path.read_text(encoding="utf-8", errors="replace")


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT))


def history_failures(files: list[Path]) -> list[str]:
    failures = []
    for path in files:
        text = _read(path)
        if not may_hold_history(text):
            continue  # the common case, found in one pass over the file
        for number, line in enumerate(text.splitlines(), 1):
            for label, matched, fix in history_hits(line):
                failures.append(f"{_rel(path)}:{number}: {label}: {matched!r} in {line.strip()[:140]!r}. Fix: {fix}.")
    return failures


def hash_failures(files: list[Path]) -> list[str]:
    failures = []
    fix = "cite the command, the physdyn version and the date instead of a commit"
    for path in files:
        text = _read(path)
        if not hash_hits(text):
            continue  # the common case, and tokenizing every file would take seconds
        if path.suffix == ".py":
            lines = python_prose(text)
        elif path.suffix == ".md":
            lines = list(enumerate(text.splitlines(), 1))
        else:  # YAML and the Makefile: their comments
            lines = [(n, line[line.index("#"):]) for n, line in enumerate(text.splitlines(), 1) if "#" in line]
        for number, line in lines:
            for token in hash_hits(line):
                failures.append(f"{_rel(path)}:{number}: a commit hash {token!r} in {line.strip()[:140]!r}. "
                                f"Fix: {fix}.")
    return failures


# ---- links --------------------------------------------------------------------------------------------------

FENCE = re.compile(r"^\s*(```|~~~)")
INLINE_CODE = re.compile(r"(`+)(.+?)\1")
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*(<[^>]*>|[^)\s]+)(?:\s+[\"'][^)]*[\"'])?\s*\)")
REF_LINK = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*(<[^>]*>|\S+)")
HTML_LINK = re.compile(r"""<(?:a|img)\b[^>]*?\b(?:href|src)\s*=\s*["']([^"']+)["']""", re.I)
SCHEME = re.compile(r"^[a-z][a-z0-9+.-]*:", re.I)


def markdown_prose_lines(text: str) -> list[tuple[int, str]]:
    """Lines outside fenced code blocks, with inline code spans blanked."""
    out, fenced = [], False
    for number, line in enumerate(text.splitlines(), 1):
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            out.append((number, INLINE_CODE.sub(lambda m: " " * len(m.group()), line)))
    return out


def link_targets(line: str) -> list[str]:
    targets = [m.group(1) for m in LINK.finditer(line)]
    targets += [m.group(1) for m in REF_LINK.finditer(line)]
    targets += [m.group(1) for m in HTML_LINK.finditer(line)]
    return [t[1:-1] if t.startswith("<") and t.endswith(">") else t for t in targets]


def slugs(heading: str) -> set[str]:
    """Anchors a heading gets: Python-Markdown's (mkdocs) and GitHub's."""
    text = re.sub(r"\s*\{[^}]*\}\s*$", "", heading)  # attr_list
    text = re.sub(r"`|\*\*|__|\*|\[([^\]]*)\]\([^)]*\)", lambda m: m.group(1) or "", text).strip()
    norm = unicodedata.normalize("NFKD", text)
    mk = re.sub(r"[-\s]+", "-", re.sub(r"[^\w\s-]", "", norm).strip().lower())
    gh = re.sub(r" ", "-", re.sub(r"[^\w\- ]", "", text.strip().lower()))
    return {mk, gh}


def anchors(text: str) -> set[str]:
    found: set[str] = set()
    counts: dict[str, int] = {}
    fenced = False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        if fenced:
            continue
        heading = re.match(r"^\s{0,3}#{1,6}\s+(.*?)\s*#*\s*$", line)
        if heading:
            for slug in slugs(heading.group(1)):
                n = counts.get(slug, 0)
                counts[slug] = n + 1
                found.add(slug)
                if n:
                    found.update({f"{slug}_{n}", f"{slug}-{n}"})
            explicit = re.search(r"\{[^}]*#([\w-]+)[^}]*\}\s*$", heading.group(1))
            if explicit:
                found.add(explicit.group(1))
        found.update(re.findall(r"""<a\b[^>]*\b(?:id|name)\s*=\s*["']([^"']+)["']""", line, re.I))
    return found


def link_problems(page: Path, text: str, docs_root: Path | None,
                  generated: dict[Path, str] | None = None) -> list[tuple[int, str, str]]:
    """(line, target, fix) for every relative link of a Markdown page that does not resolve.

    docs_root: for a docs page, the docs folder, which its links must not leave (the site holds only docs/).
    generated: pages the site build writes (absolute path -> Markdown), which count as existing."""
    generated = generated or {}
    problems = []
    for number, line in markdown_prose_lines(text):
        for target in link_targets(line):
            if not target or target.startswith("#") and not target[1:]:
                continue
            if SCHEME.match(target) or target.startswith("//"):
                continue
            path_part, _, anchor = target.partition("#")
            path_part = path_part.split("?")[0]
            if not path_part:
                resolved = page.resolve()
            elif path_part.startswith("/"):
                resolved = (ROOT / path_part.lstrip("/")).resolve()
            else:
                resolved = (page.parent / path_part).resolve()
            if not resolved.exists() and resolved not in generated:
                problems.append((number, target, "no such file; point it at one that exists (paths are "
                                                 "relative to the page's folder)"))
                continue
            if docs_root is not None and not resolved.is_relative_to(docs_root.resolve()):
                problems.append((number, target, "outside docs/, which is all the site holds; name the file in "
                                                 "backticks instead of linking it"))
                continue
            if resolved == page.resolve():
                target_text = text
            elif resolved in generated:
                target_text = generated[resolved]
            elif resolved.is_file() and resolved.suffix == ".md":
                target_text = _read(resolved)
            else:
                target_text = None
            if anchor and target_text is not None and anchor not in anchors(target_text):
                problems.append((number, target, f"no heading of {resolved.name} has the anchor #{anchor}; "
                                                 "link an existing heading or the page alone"))
    return problems


def generated_pages() -> dict[Path, str]:
    """The pages `mkdocs build` writes into the site (the CLI reference, from the parser): path -> Markdown."""
    script = ROOT / "docs" / "scripts" / "gen_cli_ref.py"
    if not script.is_file():
        return {}
    spec = importlib.util.spec_from_file_location("_gen_cli_ref", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return {(ROOT / "docs" / name).resolve(): text for name, text in module.pages().items()}


def markdown_pages() -> list[tuple[Path, Path | None]]:
    pages: list[tuple[Path, Path | None]] = []
    if (ROOT / "README.md").is_file():
        pages.append((ROOT / "README.md", None))
    docs = ROOT / "docs"
    pages += [(p, docs) for p in sorted(docs.rglob("*.md"))] if docs.is_dir() else []
    return pages


# ---- docs pages named in code ---------------------------------------------------------------------------------

DOCS_PAGE = re.compile(r"(?<![\w/.-])docs/[\w./-]*?[\w-]\.md\b")


def named_docs_pages(text: str) -> list[tuple[int, str]]:
    """(line, page) for every ``docs/....md`` a file names."""
    return [(n, m.group()) for n, line in enumerate(text.splitlines(), 1) for m in DOCS_PAGE.finditer(line)]


# ---- CLI commands in the README -----------------------------------------------------------------------------

SEPARATORS = {"&&", "||", ";", "|", "&"}
WRAPPERS = {"time", "nohup", "exec", "env"}


def command_lines(text: str) -> list[tuple[int, str]]:
    """(line, command) for shell lines in fenced blocks (not Python ones) and for inline code spans."""
    out: list[tuple[int, str]] = []
    fenced, language, pending, pending_line = False, "", "", 0
    for number, line in enumerate(text.splitlines(), 1):
        fence = FENCE.match(line)
        if fence:
            fenced = not fenced
            language = line.strip().strip("`~").strip().lower() if fenced else ""
            pending = ""
            continue
        if fenced:
            if language in {"python", "py", "pycon", "json", "yaml", "yml", "toml", "text"}:
                continue
            if not pending:
                pending_line = number
            stripped = line.rstrip()
            if stripped.endswith("\\"):
                pending += stripped[:-1] + " "
                continue
            out.append((pending_line, pending + stripped))
            pending = ""
        else:
            out += [(number, m.group(2)) for m in INLINE_CODE.finditer(line)]
    return out


def _split_words(command: str) -> list[str]:
    command = command.split(" #", 1)[0]
    command = re.sub(r"^\s*[$>]\s+", "", command)
    try:
        lexer = shlex.shlex(command, posix=True, punctuation_chars=";&|")
        lexer.whitespace_split = True
        return list(lexer)
    except ValueError:
        return command.split()


def physdyn_invocations(command: str) -> list[list[str]]:
    """The argument lists of each `physdyn ...` simple command in a shell line."""
    words, out, current = _split_words(command), [], []
    for word in [*words, ";"]:
        if word in SEPARATORS or set(word) <= set(";&|") and word:
            out.append(current)
            current = []
        else:
            current.append(word)
    invocations = []
    for simple in out:
        while simple and (re.match(r"^[A-Za-z_][A-Za-z0-9_]*=", simple[0]) or simple[0] in WRAPPERS):
            simple = simple[1:]
        if len(simple) >= 3 and re.match(r"^python[0-9.]*$", simple[0]) and simple[1] == "-m" \
                and simple[2] in {"physdyn", "physdyn.cli"}:
            simple = ["physdyn", *simple[3:]]
        if simple and simple[0] == "physdyn":
            invocations.append(simple[1:])
    return invocations


def _placeholder(word: str) -> bool:
    return bool(re.match(r"^(<.*>|\[.*\]|\{.*\}|\.\.\.|…|[A-Z_]{2,})$", word))


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _options(parser: argparse.ArgumentParser) -> set[str]:
    return {s for action in parser._actions for s in action.option_strings}


def cli_problems(args: list[str], parser: argparse.ArgumentParser) -> list[str]:
    """What in `physdyn ARGS` the parser does not have: an unknown subcommand or option."""
    problems: list[str] = []
    name = "physdyn"
    words = list(args)
    while words:
        subs = _subparsers(parser)
        # options before the subcommand belong to the current parser
        while words and words[0].startswith("-") and subs:
            option = words.pop(0).split("=", 1)[0]
            if option not in _options(parser):
                problems.append(f"`{name}` has no option {option}: use one that `{name} --help` lists")
        if not words or not subs:
            break
        word = words[0]
        if _placeholder(word):
            return problems
        if word not in subs:
            problems.append(f"`{name} {word}` is not a subcommand (`{name} --help` lists: {', '.join(subs)})")
            return problems
        words.pop(0)
        parser, name = subs[word], f"{name} {word}"
        if not _subparsers(parser):
            break
    known = _options(parser)
    for word in words:
        if re.match(r"^--?[A-Za-z][\w-]*(=.*)?$", word):
            option = word.split("=", 1)[0]
            if option not in known:
                problems.append(f"`{name}` has no option {option}: use one that `{name} --help` lists")
    return problems


# --------------------------------------------------------------------------------------------------------------
# The detectors, on small strings (so that the tree checks cannot pass on everything)
# --------------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("line", [
    f"Measured in the twenty-thi{'rd'} {WORK} on this machine.",
    f"the four{'teenth'} {WORK}'s classifier",
    f"as the 19th {WORK} found",
    f"the first {WORK} of the month",
    f"Over three {WORK}s the loss fell.",
    f"This fixes {TICKET} #26.",
    f"see {TICKET} 28 for the plan",
    f"{TICKET.title()}s #3 and #4",
    f"checked by the {CHECKED}er",
    f"after {CHECKED}",
    f"{FIXED}ed in place",
    f"This {FIXED}s the rollout",
    f"a {READ_THROUGH} found two typos",
    f"the nine{'teenth'} run",
    f"the thirt{'ieth'} figure",
    f"stored under runs/s{16}/best.ckpt",
    f"all_{1127}s{25}b gives 0.3",
    f"fast_{1126}s{18}r5/metrics.json",
    f"`s{9}/fit.log`",
])
def test_history_detector_catches(line: str) -> None:
    assert history_hits(line), line


@pytest.mark.parametrize("line", [
    "a fifth of the meshes",
    "the first and second steps",
    "the 95th percentile",
    "recommended for small stores",
    "amend the config",
    f'def store(tmp_path_factory): @pytest.fixture(scope="{WORK}")',
    f"proc = subprocess.Popen(cmd, start_new_{WORK}=True)",
    "Read through the schema: a key added takes its default",
    f"an {TICKET} with the store",
    "speeds in m/s2 and 0.5 m/s",
    "the eleven meshes, twenty steps",
    "1024 samples, 2048s of simulated time",
])
def test_history_detector_passes(line: str) -> None:
    assert not history_hits(line), (line, history_hits(line))


def test_hash_detector() -> None:
    assert hash_hits("as measured on main (e254d7d)") == ["e254d7d"]
    assert hash_hits("commits e254d7d and 3f9a0c1b2d") == ["e254d7d", "3f9a0c1b2d"]
    full = "0123456789abcdef0123456789abcdef01234567"
    assert hash_hits(f"full 40: {full}.") == [full]
    assert hash_hits("on main (2288751), and 1234567 commit") == ["2288751", "1234567"]  # digits, named a commit
    # not hashes: digits alone, no digit, too short, too long (a sha256), part of a word or a path
    assert not hash_hits("1234567 meshes, seed 20261127, a deadbeefcafe value, #1f77b4, colour ab12cd")
    assert not hash_hits("sha256 " + "ab12" * 16)
    assert not hash_hits("file_2288751a.npz and runs/a1b2c3d4e/ and x0a1b2c3d4")


def test_python_prose_reads_comments_and_docstrings_only() -> None:
    source = ('"""Module doc, at 2288751."""\n'
              'DIGEST = "e254d7d0aa"  # the e254d7d commit\n'
              'def f():\n'
              '    """Line one.\n\n    cites abc1234 here."""\n'
              '    return "f00ba12"\n')
    found = {(n, h) for n, text in python_prose(source) for h in hash_hits(text)}
    assert found == {(1, "2288751"), (2, "e254d7d"), (6, "abc1234")}


def test_docs_page_detector() -> None:
    text = "see docs/research/fast-cost.md, and\n(docs/plan.md, \"The push\"); not mydocs/x.md nor docs/figures/a.png"
    assert named_docs_pages(text) == [(1, "docs/research/fast-cost.md"), (2, "docs/plan.md")]


def test_link_detector(tmp_path: Path) -> None:
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "there.md").write_text("# Where it is\n\n## Two words\n")
    page = docs / "page.md"
    text = ("[ok](there.md) [anchor ok](there.md#two-words) [broken](missing.md)\n"
            "![picture](figures/none.png) [bad anchor](there.md#nowhere) [web](https://example.org/x.md)\n"
            "```\n[in code](ignored.md)\n```\n"
            "[out of the site](../setup.py) `[code span](ignored.md)` [self](#nowhere-here)\n"
            "[built](ref/cli.md#physdyn-plan) [built, bad anchor](ref/cli.md#nope)\n")
    (tmp_path / "setup.py").write_text("")
    page.write_text(text)
    generated = {(docs / "ref" / "cli.md").resolve(): "# physdyn plan\n"}  # written by the site build
    problems = {(n, t) for n, t, _ in link_problems(page, text, docs, generated)}
    assert problems == {(1, "missing.md"), (2, "figures/none.png"), (2, "there.md#nowhere"), (6, "../setup.py"),
                        (6, "#nowhere-here"), (7, "ref/cli.md#nope")}


def _toy_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="physdyn")
    parser.add_argument("--debug", action="store_true")
    sub = parser.add_subparsers(dest="command")
    predict = sub.add_parser("predict")
    predict.add_argument("mesh")
    predict.add_argument("--scale")
    predict.add_argument("--out", "-o")
    data = sub.add_parser("data")
    info = data.add_subparsers(dest="action").add_parser("info")
    info.add_argument("store")
    info.add_argument("--json", action="store_true")
    return parser


def test_cli_detector() -> None:
    parser = _toy_parser()
    text = ("```bash\n"
            "$ physdyn predict m.obj --scale 0.001 \\\n"
            "    --out p.json --render p.html\n"
            "physdyn --debug data info s.zarr --json && physdyn data show s.zarr\n"
            "physdyn predcit m.obj | head\n"
            "```\n"
            "Run `physdyn predict m.obj -o x.json` or `physdyn <command> --help`; `pip install physdyn`.\n"
            "```python\nphysdyn.load_predictor()  # physdyn nonsense\n```\n")
    found = []
    for number, command in command_lines(text):
        for invocation in physdyn_invocations(command):
            found += [(number, problem) for problem in cli_problems(invocation, parser)]
    assert [n for n, _ in found] == [2, 4, 5], found
    assert "no option --render" in found[0][1]
    assert "`physdyn data show` is not a subcommand" in found[1][1]
    assert "`physdyn predcit` is not a subcommand" in found[2][1]


# --------------------------------------------------------------------------------------------------------------
# The tree
# --------------------------------------------------------------------------------------------------------------

def _report(failures: list[str], what: str) -> str:
    shown = "\n".join(failures[:60])
    more = f"\n... and {len(failures) - 60} more" if len(failures) > 60 else ""
    return f"{len(failures)} {what}:\n{shown}{more}"


def test_the_scan_covers_the_tree() -> None:
    scanned = {_rel(path) for path in scanned_files()}
    for expected in ("README.md", "physdyn/cli/__init__.py", "tests/conftest.py", "benchmarks/frontier.py"):
        assert expected in scanned, f"{expected} is not scanned: the file list of this test is wrong"
    assert any(name.startswith("docs/") and name.endswith(".md") for name in scanned)
    assert "tests/test_docs_hygiene.py" in scanned  # it spells its patterns in pieces and passes its own check
    assert "CHANGELOG.md" not in scanned


def test_no_development_history() -> None:
    failures = history_failures(scanned_files())
    assert not failures, _report(failures, "lines tell the history of the work instead of what things are")


def test_no_commit_hashes_in_prose() -> None:
    failures = hash_failures(scanned_files())
    assert not failures, _report(failures, "commit hashes cited in prose, comments or docstrings")


def test_relative_links_resolve() -> None:
    failures = []
    generated = generated_pages()
    pages = [(page, docs_root, _read(page)) for page, docs_root in markdown_pages()]
    pages += [(path, ROOT / "docs", text) for path, text in generated.items()]
    for page, docs_root, text in pages:
        for number, target, fix in link_problems(page, text, docs_root, generated):
            failures.append(f"{_rel(page)}:{number}: link {target!r}: {fix}.")
    assert not failures, _report(failures, "broken relative links")


def test_docs_pages_named_in_code_exist() -> None:
    failures = []
    for path in scanned_files():
        if path.is_relative_to(ROOT / "docs") or path.name == "README.md" and path.parent == ROOT:
            continue  # pages link each other (test_relative_links_resolve)
        for number, page in named_docs_pages(_read(path)):
            if not (ROOT / page).is_file():
                failures.append(f"{_rel(path)}:{number}: names {page}, which does not exist. Fix: name the page "
                                "that holds it (docs/research/index.md lists the research notes).")
    assert not failures, _report(failures, "docs pages named in code, tests or configs that do not exist")


def test_readme_commands_exist() -> None:
    from physdyn.cli import build_parser

    parser = build_parser()
    readme = ROOT / "README.md"
    failures, checked = [], 0
    for number, command in command_lines(readme.read_text(encoding="utf-8")):
        for invocation in physdyn_invocations(command):
            checked += 1
            for problem in cli_problems(invocation, parser):
                failures.append(f"README.md:{number}: {command.strip()[:140]!r}: {problem}.")
    assert checked, "found no `physdyn` command in README.md's code: the README or this test's reading of it is wrong"
    assert not failures, _report(failures, "README commands the CLI does not have")


def predict_velocity_problems(invocation: list[str]) -> list[str]:
    """`physdyn predict` of one mesh needs both post-push velocities; a command that gives one only fails."""
    if not invocation or invocation[0] != "predict" or "--batch" in invocation or "--help" in invocation:
        return []
    given = [flag for flag in ("--lin-vel", "--ang-vel") if flag in invocation]
    missing = [flag for flag in ("--lin-vel", "--ang-vel") if flag not in invocation]
    return [f"gives {given[0]} without {missing[0]}"] if len(given) == 1 else []


def test_predict_velocity_detector() -> None:
    assert predict_velocity_problems(["predict", "m.obj", "--lin-vel", "1", "0", "0"]) == ["gives --lin-vel without --ang-vel"]
    assert not predict_velocity_problems(["predict", "m.obj", "--lin-vel", "1", "0", "0", "--ang-vel", "0", "0", "0"])
    assert not predict_velocity_problems(["predict", "--batch", "r.jsonl", "--out-dir", "out"])
    assert not predict_velocity_problems(["fit", "--config", "c.yaml"])


def test_predict_commands_in_the_docs_give_both_velocities() -> None:
    failures, checked = [], 0
    pages = [(page, _read(page)) for page, _ in markdown_pages()] + list(generated_pages().items())
    for page, text in pages:
        for number, command in command_lines(text):
            for invocation in physdyn_invocations(command):
                checked += invocation[:1] == ["predict"]
                failures += [f"{_rel(page)}:{number}: {command.strip()[:140]!r}: {problem}; `physdyn predict` of one "
                             "mesh needs both --lin-vel and --ang-vel." for problem in predict_velocity_problems(invocation)]
    assert checked, "found no `physdyn predict` command in the docs: the pages or this test's reading of them is wrong"
    assert not failures, _report(failures, "predict commands that would fail")
