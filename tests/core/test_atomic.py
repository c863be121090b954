"""Atomic outputs: the target changes only by a rename, and what a killed run left behind is
cleaned by the next write of the same output."""

import os
import signal
import subprocess
import sys
import time

import pytest

from fignetctl.core.atomic import (
    StagedDirectory,
    atomic_directory,
    atomic_path,
    remove_stale_temporaries,
    write_json,
)

WRITER = """
import sys, time
from fignetctl.core.atomic import atomic_directory, atomic_path
target, kind = sys.argv[1], sys.argv[2]
if kind == "file":
    with atomic_path(target) as tmp:
        tmp.write_bytes(b"half")
        print("writing", flush=True)
        time.sleep(60)
else:
    with atomic_directory(target, ("*.png",)) as tmp:
        (tmp / "a.png").write_bytes(b"half")
        print("writing", flush=True)
        time.sleep(60)
"""


def _killed_mid_write(target, kind):
    """Run a writer in another process and kill -9 it while its temporary exists."""
    process = subprocess.Popen([sys.executable, "-c", WRITER, str(target), kind], stdout=subprocess.PIPE)
    assert process.stdout.readline().strip() == b"writing"
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=30)


def _leftovers(folder, name):
    return sorted(entry.name for entry in folder.iterdir() if entry.name.startswith(f".{name}."))


@pytest.mark.parametrize("kind", ["file", "folder"])
def test_the_next_write_removes_what_a_killed_writer_left(tmp_path, kind):
    target = tmp_path / ("out.h5" if kind == "file" else "frames")
    name = "out" if kind == "file" else "frames"
    if kind == "file":
        target.write_bytes(b"earlier good output")
    _killed_mid_write(target, kind)
    assert len(_leftovers(tmp_path, name)) == 1
    if kind == "file":
        assert target.read_bytes() == b"earlier good output"
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"new")
        assert target.read_bytes() == b"new"
    else:
        assert not target.exists()
        with atomic_directory(target, ("*.png",)) as tmp:
            (tmp / "b.png").write_bytes(b"new")
        assert sorted(p.name for p in target.iterdir()) == ["b.png"]
    assert _leftovers(tmp_path, name) == []


def test_a_running_writers_temporary_is_left_alone(tmp_path):
    mine = tmp_path / f".out.{os.getpid()}-abc.tmp.h5"
    mine.write_bytes(b"in progress")
    other = tmp_path / ".out.notapid-abc.tmp.h5"
    other.write_bytes(b"not ours")
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / f".out.{dead.pid}-xyz.tmp.h5"
    stale.write_bytes(b"left by a killed run")
    time.sleep(0.01)
    assert remove_stale_temporaries(tmp_path, "out", ".tmp.h5") == [stale]
    assert mine.exists() and other.exists() and not stale.exists()


def test_a_failed_write_keeps_the_target_and_leaves_nothing(tmp_path):
    target = tmp_path / "out.json"
    target.write_text("good")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("bad")
        raise RuntimeError("failed half way")
    assert target.read_text() == "good" and _leftovers(tmp_path, "out") == []
    with pytest.raises(RuntimeError), StagedDirectory(tmp_path / "dir", ("*",)) as staged:
        (staged.path / "x").write_text("bad")
        raise RuntimeError("failed half way")
    assert not (tmp_path / "dir").exists() and _leftovers(tmp_path, "dir") == []


def test_write_json_writes_what_json_dumps_gives_and_keeps_the_target_when_it_cannot(tmp_path):
    import json

    target = tmp_path / "out.json"
    document = {"a": [1, 2.5], "b": {"c": None}}
    write_json(target, document)
    assert target.read_text() == json.dumps(document, indent=1)
    write_json(target, document, indent=2, sort_keys=True)
    assert target.read_text() == json.dumps(document, indent=2, sort_keys=True)
    with pytest.raises(TypeError):
        write_json(target, {"not json": object()})
    assert target.read_text() == json.dumps(document, indent=2, sort_keys=True)
    assert _leftovers(tmp_path, "out") == []
