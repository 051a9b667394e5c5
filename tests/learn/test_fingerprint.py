"""The arithmetic fingerprints: the same on every call, and changed by a change of the numbers computed."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from replicate.learn import fingerprint, maddpg


def test_the_arithmetic_fingerprint_names_the_numbers_not_the_code(monkeypatch):
    """The fingerprint is the same on every call, and changes with a change of the computed numbers in either half
    of training: the world's geometry (a coarser union raster) and the update (one matmul form rounded through
    float64)."""
    first = fingerprint.fingerprint()
    fingerprint.fingerprint.cache_clear()
    assert fingerprint.fingerprint() == first and len(first) == 16
    changed = []
    with monkeypatch.context() as m:
        m.setattr(fingerprint, "COVERAGE", dataclasses.replace(fingerprint.COVERAGE, raster_spacing=0.02))
        fingerprint.fingerprint.cache_clear()
        changed.append(fingerprint.fingerprint())
    with monkeypatch.context() as m:
        m.setattr(maddpg, "stacked_matmul", lambda a, b: torch.bmm(a.double(), b.double()).float())
        fingerprint.fingerprint.cache_clear()
        changed.append(fingerprint.fingerprint())
    fingerprint.fingerprint.cache_clear()
    assert fingerprint.fingerprint() == first
    assert first not in changed and len(set(changed)) == 2


def test_the_general_and_search_fingerprints_name_their_own_numbers(monkeypatch):
    """The general policy's fingerprint changes with its learner's arithmetic (one layer's matmul rounded through
    float64) and the per-region one does not; a study's changes with TPE's arithmetic (its inverse CDF rounded
    through float32); each is stable and the three differ."""
    from replicate.learn import shared_maddpg

    general, search, regions = (fingerprint.general_fingerprint(), fingerprint.search_fingerprint(),
                                fingerprint.fingerprint())
    assert len({general, search, regions}) == 3
    for fp in (fingerprint.general_fingerprint, fingerprint.search_fingerprint):
        fp.cache_clear()
    assert (fingerprint.general_fingerprint(), fingerprint.search_fingerprint()) == (general, search)

    class RoundedLinear(torch.nn.Linear):
        def forward(self, x):
            return torch.nn.functional.linear(x.double(), self.weight.double(), self.bias.double()).float()

    with monkeypatch.context() as m:
        m.setattr(shared_maddpg.nn, "Linear", RoundedLinear)
        fingerprint.general_fingerprint.cache_clear()
        fingerprint.fingerprint.cache_clear()
        assert fingerprint.general_fingerprint() != general and fingerprint.fingerprint() == regions
    with monkeypatch.context() as m:
        from optuna.samplers._tpe import _truncnorm

        ppf = _truncnorm.ppf  # TPE's inverse CDF, which turns its uniform draws into proposals
        m.setattr(_truncnorm, "ppf", lambda q, a, b: ppf(q, a, b).astype(np.float32).astype(np.float64))
        fingerprint.search_fingerprint.cache_clear()
        assert fingerprint.search_fingerprint() != search
    for fp in (fingerprint.general_fingerprint, fingerprint.search_fingerprint, fingerprint.fingerprint):
        fp.cache_clear()
