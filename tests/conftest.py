from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
os.environ.setdefault("DVC_NO_ANALYTICS", "1")


def pytest_configure(config):
    """The tests train in this process: the settings of a training process (one thread, as the references)."""
    from replicate.learn.process import training_process

    training_process()


@pytest.fixture(scope="session")
def params():
    from replicate.core.params import load_params

    return load_params(ROOT / "params.yaml")


@pytest.fixture(scope="session")
def regions(params):
    """The three regions of the paper, built once per session (Bedok from the bundled outline)."""
    from replicate.world.regions import make_region

    return {
        name: make_region(name, params.regions[name], params.world.region_area, root=ROOT)
        for name in ("square", "rectangle", "bedok")
    }


@pytest.fixture
def replicate(capsys, monkeypatch):
    """The ``replicate`` command run in this process from the repository's root, as a user runs it:
    ``replicate(*argv)`` → (exit code, what it wrote to stderr); what it printed is then ``replicate.out``. A
    traceback fails the test where it is raised."""
    from replicate.toolkit.cli import main

    monkeypatch.chdir(ROOT)

    def run(*argv: str) -> tuple[int, str]:
        code = main(list(argv))
        printed = capsys.readouterr()
        run.out = printed.out
        return code, printed.err

    return run


@pytest.fixture(autouse=True)
def progress_as_the_package_starts():
    """A command run in this process asks for progress log lines (its stderr is no terminal): not for the next."""
    yield
    from replicate.core import progress

    progress.log_lines(False)
