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
