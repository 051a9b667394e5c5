"""The source files a ``dvc.yaml`` stage runs: what its notebook imports from the package, followed through the
package's import graph (grimp; imports inside functions included). ``test_stage_deps`` checks that every stage
lists exactly these, so a moved or new module cannot silently drop out of a stage's dependencies.

``python -m tests.pipeline.stage_sources`` prints each stage's derived list, ready to paste into ``dvc.yaml``.
"""

from __future__ import annotations

import json
import re
from functools import cache
from pathlib import Path

import grimp
import yaml

ROOT = Path(__file__).resolve().parents[2]
IMPORT = re.compile(r"^\s*from (replicate[\w.]*) import ([\w, ]+)|^\s*import (replicate[\w.]*)", re.M)


@cache
def graph() -> grimp.ImportGraph:
    return grimp.build_graph("replicate", include_external_packages=False)


def notebook_modules(notebook: Path) -> set[str]:
    """The package's modules a notebook's code cells import (``from replicate.x import y`` names module y when
    it is one, else x)."""
    cells = json.loads(notebook.read_text())["cells"]
    code = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
    modules = set()
    for frm, names, plain in IMPORT.findall(code):
        if plain:
            modules.add(plain)
            continue
        for name in (n.strip() for n in names.split(",")):
            modules.add(f"{frm}.{name}" if f"{frm}.{name}" in graph().modules else frm)
    return modules


def module_file(module: str) -> Path:
    path = ROOT / "src" / Path(*module.split("."))
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


def stage_sources(notebook: Path) -> list[str]:
    """Every source file (relative to the repository) a stage running ``notebook`` imports, directly or not;
    packages' ``__init__.py`` files (docstrings only) left out."""
    modules = notebook_modules(notebook)
    for m in list(modules):
        modules |= graph().find_upstream_modules(m)
    files = {module_file(m) for m in modules}
    templates = {t for f in files for t in f.parent.glob("*.j2")}  # read by the modules beside them
    return sorted(str(f.relative_to(ROOT)) for f in files | templates if f.name != "__init__.py")


def stages() -> dict[str, dict]:
    return yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]


def stage_notebook(stage: dict) -> Path:
    return ROOT / next(d for d in stage["deps"] if d.startswith("notebooks/") and d.endswith(".ipynb"))


def listed_sources(stage: dict) -> list[str]:
    return sorted(d for d in stage["deps"] if d.startswith("src/replicate/") and d.endswith((".py", ".j2")))


if __name__ == "__main__":
    for name, stage in stages().items():
        print(f"{name}:")
        for path in stage_sources(stage_notebook(stage)):
            print(f"      - {path}")
