"""Atomic file writes: the old file or the whole new one, never a truncated mix."""

from __future__ import annotations

import pytest

from elastic_gym.runtime.atomic import atomic_file, write_bytes, write_text


def test_a_write_that_fails_midway_keeps_the_old_file_and_leaves_no_scratch(tmp_path):
    target = tmp_path / "card.json"
    write_text(target, "old")
    with pytest.raises(OSError, match="disk full"), atomic_file(target) as stream:
        stream.write("new, half")
        raise OSError("disk full")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["card.json"]


def test_a_finished_write_replaces_the_file_whole(tmp_path):
    target = tmp_path / "figure.png"
    write_bytes(target, b"\x89PNG old")
    write_bytes(target, b"\x89PNG new")
    assert target.read_bytes() == b"\x89PNG new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["figure.png"]


def test_only_whole_file_modes_are_accepted(tmp_path):
    with pytest.raises(ValueError, match="whole files"), atomic_file(tmp_path / "x", "a"):
        pass
    assert not list(tmp_path.iterdir())


def test_a_new_file_gets_the_umask_mode_and_a_replaced_one_keeps_its_mode(tmp_path):
    import os
    import stat

    umask = os.umask(0o022)
    try:
        fresh = write_text(tmp_path / "page.md", "new")
        assert stat.S_IMODE(fresh.stat().st_mode) == 0o644  # as open() would, not mkstemp's 0o600
        kept = tmp_path / "card.json"
        kept.write_text("old")
        kept.chmod(0o640)
        write_text(kept, "new")
        assert stat.S_IMODE(kept.stat().st_mode) == 0o640
    finally:
        os.umask(umask)
