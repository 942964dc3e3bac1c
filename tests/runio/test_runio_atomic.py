"""runio.runfolder.atomic_file: a file written whole or not at all, and no temporary file left."""

import os
import stat

import pytest

from skyherd.flight.mavlink.keys import load_key, save_key
from skyherd.runio.runfolder import atomic_file, atomic_write_text, filter_jsonl


def test_a_whole_file_replaces_the_old_one(tmp_path):
    path = tmp_path / "config.json"
    atomic_write_text(path, "old")
    atomic_write_text(path, "new")
    assert path.read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == [
        "config.json"
    ]


@pytest.mark.parametrize("error", [ValueError("the caller's"), KeyboardInterrupt()])
def test_writing_that_raises_keeps_the_old_file_and_no_temporary(tmp_path, error):
    """Whatever ends the writing (the caller's own error, Ctrl-C), the old content stays and
    the temporary file goes (it was kept for anything but an OSError)."""
    path = tmp_path / "events.jsonl"
    path.write_text('{"a": 1}\n')
    with pytest.raises(type(error)):
        with atomic_file(path, "w", encoding="utf-8") as f:
            f.write("half")
            raise error
    assert path.read_text() == '{"a": 1}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["events.jsonl"]


def test_filter_jsonl_whose_test_raises_keeps_the_file(tmp_path):
    path = tmp_path / "events.jsonl"
    path.write_text('{"i": 1}\n{"i": 2}\n')

    def keep(rec):
        if rec["i"] == 2:
            raise RuntimeError("a bad test")
        return True

    with pytest.raises(RuntimeError):
        filter_jsonl(path, keep)
    assert path.read_text() == '{"i": 1}\n{"i": 2}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["events.jsonl"]
    assert filter_jsonl(path, lambda r: r["i"] == 1) == 1 and path.read_text() == '{"i": 1}\n'


def test_a_key_file_is_made_owner_only_and_replaced_whole(tmp_path):
    path = tmp_path / "keys" / "uav.key"
    save_key(path, bytes(range(32)))
    path.chmod(0o644)  # an old key file others could read
    save_key(path, bytes(32 * [7]))
    assert load_key(path) == bytes(32 * [7])
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    assert sorted(p.name for p in path.parent.iterdir()) == ["uav.key"]
