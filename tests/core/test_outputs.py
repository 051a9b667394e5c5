"""An output's lock: a folder where it cannot be written is named, not an OS error about a hidden lock file."""

from __future__ import annotations

import errno

import pytest

from replicate.core import outputs
from replicate.core.schema import ConfigError


def test_an_output_on_a_read_only_disk_is_named(tmp_path, monkeypatch):
    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(outputs.os, "open", read_only)
    with pytest.raises(ConfigError, match=r"--out .*/run: cannot be written there \(Read-only file system\); "
                                          "choose a writable folder"):
        with outputs.locked(tmp_path / "run"):
            pass


def test_a_result_left_aside_by_a_killed_command_is_put_back(tmp_path):
    """`cover --force` killed with kill -9 leaves its half-written folder and the old result aside: the next
    command to claim the output finds the old result in place (and is then refused without --force)."""
    out = tmp_path / "cover"
    (tmp_path / ".cover.replaced").mkdir()
    (tmp_path / ".cover.replaced" / "summary.json").write_text("the old result")
    out.mkdir()
    (out / "partial").write_text("half")
    with pytest.warns(UserWarning, match="put back the result that a killed command had moved aside"):
        with outputs.locked(out):
            assert (out / "summary.json").read_text() == "the old result" and not (out / "partial").exists()
    assert not (tmp_path / ".cover.replaced").exists()


def test_an_output_under_a_file_is_named(tmp_path):
    (tmp_path / "afile").write_text("x")
    with pytest.raises(ConfigError, match=r"--out .*afile/run: cannot be written there \(File exists\)"):
        with outputs.locked(tmp_path / "afile" / "run"):
            pass
