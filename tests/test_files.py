"""mepnet.files: outputs appear whole or not at all, with the umask's permissions, and never
replace anything mepnet did not write."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from mepnet.errors import OutputError
from mepnet.files import (
    MANIFEST,
    atomic_folder,
    atomic_write_json,
    check_output_file,
    check_replaceable,
    remove_stale_temporaries,
)


def dead_pid() -> int:
    """The pid of a process that has exited."""
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_atomic_folder_writes_a_manifest_and_replaces_only_its_own(tmp_path: Path):
    out = tmp_path / "out"
    with atomic_folder(out, "mepnet.test") as tmp:
        (tmp / "a.txt").write_text("1")
        (tmp / "sub").mkdir()
        (tmp / "sub" / "b.txt").write_text("2")
        assert not out.exists()  # nothing at the target until the end
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest["writer"] == "mepnet.test" and sorted(manifest["files"]) == [
        "a.txt",
        "sub/b.txt",
    ]
    assert len(manifest["files"]["a.txt"]) == 64  # a sha256 per file
    with atomic_folder(out, "mepnet.test") as tmp:  # its own earlier output: replaced
        (tmp / "c.txt").write_text("3")
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "c.txt"]
    # somebody's file inside: refused before and nothing changes
    (out / "thesis.txt").write_text("years of work")
    with pytest.raises(OutputError, match="thesis.txt, which mepnet did not write"):
        with atomic_folder(out, "mepnet.test"):
            pass
    assert (out / "thesis.txt").read_text() == "years of work"
    (out / "thesis.txt").unlink()
    (out / "c.txt").write_text("edited")  # a file mepnet wrote, changed since: refused
    with pytest.raises(OutputError, match="c.txt was changed since mepnet wrote it"):
        check_replaceable(out, "mepnet.test")
    (out / "c.txt").write_text("3")
    (out / "my-empty-folder").mkdir()  # even an empty folder of somebody's is kept
    with pytest.raises(OutputError, match="my-empty-folder, which mepnet did not write"):
        check_replaceable(out, "mepnet.test")
    (out / "my-empty-folder").rmdir()
    check_replaceable(out, "mepnet.test")
    (out / "thesis.txt").write_text("years of work")
    # another command's folder, a folder without manifest, a file: refused
    with pytest.raises(OutputError, match="was written by mepnet.test, not mepnet.other"):
        check_replaceable(out, "mepnet.other")
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "x").write_text("")
    with pytest.raises(OutputError, match="not written by mepnet"):
        check_replaceable(foreign, "mepnet.test")
    with pytest.raises(OutputError, match="not a folder"):
        check_replaceable(foreign / "x", "mepnet.test")
    check_replaceable(tmp_path / "empty-or-absent", "mepnet.test")


def test_atomic_folder_leaves_nothing_behind_on_error(tmp_path: Path):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        with atomic_folder(out, "mepnet.test") as tmp:
            (tmp / "half.txt").write_text("half")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(OutputError, match="already exists"):
        out.mkdir()
        with atomic_folder(out, "mepnet.test", replace=False):
            pass


def test_outputs_follow_the_umask(tmp_path: Path):
    old = os.umask(0o022)
    try:
        with atomic_folder(tmp_path / "out", "mepnet.test") as tmp:
            (tmp / "a.txt").write_text("1")
        atomic_write_json(tmp_path / "doc.json", {"a": 1})
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "out").stat().st_mode) == 0o755
    assert stat.S_IMODE((tmp_path / "out" / MANIFEST).stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "doc.json").stat().st_mode) == 0o644


def test_stale_temporaries_of_dead_processes_go_live_ones_stay(tmp_path: Path):
    dead = tmp_path / f".tmp-mepnet-out-{dead_pid()}-abc123"
    live = tmp_path / f".tmp-mepnet-out-{os.getpid()}-def456"
    other = tmp_path / f".tmp-mepnet-manual_00000001-{dead_pid()}-ghi789"
    for d in (dead, live, other):
        d.mkdir()
        (d / "f").write_text("")
    similar = tmp_path / f".tmp-mepnet-out-9-{dead_pid()}-jkl012"  # the temporary of "out-9"
    similar.mkdir()
    users = tmp_path / f".tmp-out-{dead_pid()}-userdata"  # not a mepnet name: never touched
    users.mkdir()
    assert remove_stale_temporaries(tmp_path, "out") == 1
    assert not dead.exists() and live.exists() and other.exists() and similar.exists()
    assert users.exists()
    assert remove_stale_temporaries(tmp_path) == 2  # any name
    assert not other.exists() and not similar.exists() and live.exists() and users.exists()


def test_output_file_checks(tmp_path: Path):
    (tmp_path / "mine.json").write_text('{"a": 1}')
    with pytest.raises(OutputError, match="not written by mepnet.eval"):
        check_output_file(tmp_path / "mine.json", "mepnet.eval")
    (tmp_path / "ours.json").write_text('{"written_by": "mepnet.eval"}')
    check_output_file(tmp_path / "ours.json", "mepnet.eval")
    os.symlink(tmp_path / "ours.json", tmp_path / "link.json")
    with pytest.raises(OutputError, match="not a regular file"):
        check_output_file(tmp_path / "link.json", "mepnet.eval")
    with pytest.raises(OutputError, match="not a regular file"):
        atomic_write_json("/dev/null", {})
    for p in ("mine.json", "ours.json", "link.json"):
        (tmp_path / p).unlink()
    with pytest.raises(OutputError, match="is a folder"):
        check_output_file(tmp_path)
    with pytest.raises(OutputError, match="does not exist"):
        check_output_file(tmp_path / "missing" / "m.json")
    with pytest.raises(OutputError, match="is a folder"):
        atomic_write_json(tmp_path, {})
    assert list(tmp_path.iterdir()) == []  # no stray temporary
    check_output_file(tmp_path / "m.json")


def test_inputs_must_be_regular_files(tmp_path: Path):
    from mepnet.errors import InputError
    from mepnet.files import regular_input

    os.mkfifo(tmp_path / "fifo")
    with pytest.raises(InputError, match="not a regular file"):
        regular_input(tmp_path / "fifo", "LDraw file")
    with pytest.raises(InputError, match="is a folder"):
        regular_input(tmp_path)
    with pytest.raises(InputError, match="no such"):
        regular_input(tmp_path / "missing")


def test_a_folder_that_appears_meanwhile_is_not_replaced_without_leave(tmp_path: Path):
    out = tmp_path / "out"
    with pytest.raises(OutputError, match="appeared while mepnet was writing"):
        with atomic_folder(out, "mepnet.test", replace=False) as tmp:
            (tmp / "a.txt").write_text("mine")
            out.mkdir()  # another run finished first
            (out / "theirs.txt").write_text("theirs")
    assert sorted(p.name for p in out.iterdir()) == ["theirs.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
