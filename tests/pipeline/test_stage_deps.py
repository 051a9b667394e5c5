"""Each ``dvc.yaml`` stage lists exactly the source files its notebook runs (derived from the import graph), and
the committed outputs are what ``dvc.lock`` records, by hash."""

from __future__ import annotations

import pytest

from ..conftest import ROOT
from .stage_sources import listed_sources, stage_notebook, stage_sources, stages


@pytest.mark.parametrize("name", list(stages()))
def test_a_stage_lists_every_source_file_its_notebook_imports(name):
    stage = stages()[name]
    derived, listed = stage_sources(stage_notebook(stage)), listed_sources(stage)
    missing, extra = sorted(set(derived) - set(listed)), sorted(set(listed) - set(derived))
    assert not missing and not extra, (f"dvc.yaml {name}: add {missing}, drop {extra} "
                                       "(`python -m tests.pipeline.stage_sources` prints every stage's list)")


def test_the_committed_outputs_are_the_ones_dvc_lock_records():
    """A fresh clone shows every result without training, and ``dvc repro`` there has nothing to do: every stage's
    dependencies, parameters and outputs hash to what ``dvc.lock`` says."""
    if not (ROOT / "dvc.lock").exists():
        pytest.skip("the pipeline has not been run and committed yet (dvc.lock absent)")
    from dvc.repo import Repo

    with Repo(str(ROOT)) as repo:
        changed = repo.status()
    assert not changed, f"stages whose files differ from dvc.lock: {changed}"
