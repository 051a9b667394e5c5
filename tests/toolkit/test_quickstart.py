"""The README's Quickstart, run as written in a fresh clone, leaves the pipeline as it found it: every output goes
to ``my-runs/`` (ignored by git, never read by the pipeline), and ``dvc status`` still finds nothing to do."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys

import pytest

from ..conftest import ROOT


def quickstart_commands() -> list[list[str]]:
    """The Quickstart's ``replicate`` lines, with the README's placeholder lake given a real file and the line that
    only shows the ``--set`` syntax (``...``) left out."""
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"## Quickstart.*?```bash\n(.*?)```", readme, re.S).group(1)
    commands = []
    for line in block.splitlines():
        words = shlex.split(line.split("#")[0])
        if words and words[0] == ".venv/bin/replicate" and "..." not in words:
            commands.append([w if w != "my_lake.geojson" else "data/bedok_outline.geojson" for w in words[1:]])
    return commands


def test_the_quickstart_is_read_from_the_readme():
    commands = quickstart_commands()
    verbs = ("plan", "cover", "train", "evaluate", "export", "--set")
    assert len(commands) >= 4 and all(c[0] in verbs for c in commands)
    assert all(any(w.startswith("my-runs/") for w in c) or c[0] in ("evaluate", "export") for c in commands)


@pytest.mark.slow
def test_the_quickstart_leaves_the_pipeline_as_it_found_it(tmp_path):
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "--quiet", "--local", str(ROOT), str(clone)], check=True)
    env = {**os.environ, "DVC_NO_ANALYTICS": "1", "PYTHONUNBUFFERED": "1"}
    for words in quickstart_commands():
        done = subprocess.run([sys.executable, "-m", "replicate", *words], cwd=clone, env=env, capture_output=True,
                              text=True, timeout=1200)
        assert done.returncode == 0, (words, done.stderr[-2000:])
    assert (clone / "my-runs" / "sq" / "policy.pt").is_file()
    assert (clone / "my-runs" / "lake" / "summary.json").is_file()
    untracked = subprocess.run(["git", "status", "--porcelain"], cwd=clone, capture_output=True, text=True).stdout
    assert untracked == "", untracked
    status = subprocess.run([sys.executable, "-m", "dvc", "status"], cwd=clone, env=env, capture_output=True,
                            text=True)
    assert "Data and pipelines are up to date" in status.stdout, status.stdout + status.stderr
