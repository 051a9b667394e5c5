"""The package's layout as a test: wings import downwards only, no module imports itself back, modules and
functions stay a size a reader takes in, and the CLI starts without torch.

The layers themselves are import-linter's contract (``pyproject.toml``, ``make lint``); this test checks the same
order over grimp's graph, so ``make test`` fails on an upward import too.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys

import grimp
import pytest

from .conftest import ROOT

WINGS = ("core", "world", "learn", "compare", "toolkit", "pipeline")  # bottom to top
MAX_MODULE_LINES = 400
MAX_FUNCTION_LINES = 60
LONG = "Long on purpose:"  # a longer function's docstring says why, after these words


@pytest.fixture(scope="module")
def graph() -> grimp.ImportGraph:
    return grimp.build_graph("replicate", include_external_packages=False)


def wing(module: str) -> int:
    parts = module.split(".")
    return WINGS.index(parts[1]) if len(parts) > 1 and parts[1] in WINGS else -1


def test_every_module_lives_in_a_wing(graph):
    loose = sorted(m for m in graph.modules if wing(m) < 0 and m not in ("replicate", "replicate.__main__"))
    assert not loose, f"modules outside the wings {WINGS}: {loose}"


def test_wings_import_only_the_wings_below_them(graph):
    upward = sorted(f"{a} -> {b}" for a in graph.modules for b in graph.find_modules_directly_imported_by(a)
                    if wing(a) >= 0 and wing(b) > wing(a))
    assert not upward, "imports that run upward:\n" + "\n".join(upward)


def test_no_import_cycles(graph):
    cycles = []
    for module in sorted(graph.modules):
        for imported in graph.find_modules_directly_imported_by(module):
            if module != imported and graph.chain_exists(imported, module):
                cycles.append(f"{module} -> {imported} -> ... -> {module}")
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_modules_and_functions_stay_readable():
    too_long = []
    for path in sorted((ROOT / "src" / "replicate").rglob("*.py")):
        source = path.read_text()
        name = path.relative_to(ROOT / "src")
        if len(source.splitlines()) > MAX_MODULE_LINES:
            too_long.append(f"{name}: {len(source.splitlines())} lines")
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES and LONG not in (ast.get_docstring(node) or ""):
                    too_long.append(f"{name}: {node.name} is {lines} lines")
    assert not too_long, (f"over {MAX_MODULE_LINES} lines a module or {MAX_FUNCTION_LINES} a function (a function "
                          f"may say why, after {LONG!r} in its docstring):\n" + "\n".join(too_long))


def test_the_command_line_starts_without_torch():
    """``replicate --help`` and a verb's own checks come before torch's import (about a second of start-up)."""
    code = ("import sys; from replicate.toolkit.cli.command import build_parser; build_parser().format_help(); "
            "print(sorted(m for m in ('torch', 'numba', 'geopandas', 'matplotlib') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_readme_reads_in_a_minute():
    """README.md: at most 100 lines, and no paragraph of prose over 80 words (code, tables and lists aside)."""
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 100
    prose = re.sub(r"```.*?```", "", text, flags=re.S)
    long = [p[:60] for p in prose.split("\n\n")
            if not p.lstrip().startswith(("|", "- ", "#")) and len(p.split()) > 80]
    assert not long, f"README paragraphs over 80 words: {long}"
