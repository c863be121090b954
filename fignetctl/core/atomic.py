"""Atomic outputs: write to a temporary file (or folder) beside the target, then rename.

A temporary's name holds the writing process's id (`.{name}.{pid}-{random}.tmp…`): one that a
killed run left behind (kill -9, a power cut) is removed by the next write of the same output
once no process of that id is running.
"""

import contextlib
import fnmatch
import glob
import json
import os
import shutil
import tempfile
from pathlib import Path

from fignetctl.errors import FignetError


def write_json(path, document, **dumps_options) -> None:
    """`document` as JSON at `path`, atomically; `dumps_options` go to json.dumps (indent=1 unless
    given)."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(document, **{"indent": 1, **dumps_options}))


@contextlib.contextmanager
def atomic_path(path, suffix=None):
    """Yield a temporary path in the target's folder; rename it onto `path` on success.

    On any exception the temporary file is removed and an existing `path` is left
    untouched, so a failed command never destroys an earlier good output.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix if suffix is None else suffix
    remove_stale_temporaries(path.parent, path.stem, f".tmp{suffix}")
    # The real extension stays last: some writers (PyAV, OpenCV) choose the format by it.
    fd, tmp = tempfile.mkstemp(prefix=_prefix(path.stem), suffix=f".tmp{suffix}", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    os.chmod(tmp, 0o666 & ~_current_umask())  # mkstemp makes 0600; outputs get the usual mode
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


class StagedDirectory:
    """A folder built in a temporary sibling of `target` and moved onto it by `commit()`.

    Until then an existing `target` (an earlier good result) is untouched, and `discard()` (or
    leaving the `with` block by an exception) removes the temporary folder. `owned` names the
    entries the command writes (glob patterns): a `target` that holds anything else is refused,
    at once and again at commit, because committing replaces the whole folder.
    """

    def __init__(self, target, owned):
        self.target, self.owned = Path(target), tuple(owned)
        self.check_owned()
        self.target.parent.mkdir(parents=True, exist_ok=True)
        for suffix in (".tmp", ".old"):
            remove_stale_temporaries(self.target.parent, self.target.name, suffix)
        self.path = Path(
            tempfile.mkdtemp(prefix=_prefix(self.target.name), suffix=".tmp", dir=self.target.parent)
        )
        os.chmod(self.path, 0o777 & ~_current_umask())

    def check_owned(self) -> None:
        """FignetError when the existing target holds entries this command does not write."""
        if not self.target.is_dir():
            return
        foreign = sorted(
            entry.name
            for entry in self.target.iterdir()
            if not any(fnmatch.fnmatchcase(entry.name, pattern) for pattern in self.owned)
        )
        if foreign:
            shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
            raise FignetError(
                f"{self.target}: holds {shown}, which this command does not write; replacing the "
                "folder would delete them, so move them or write elsewhere"
            )

    def commit(self) -> Path:
        self.check_owned()
        old = None
        if self.target.exists():
            old = Path(
                tempfile.mkdtemp(prefix=_prefix(self.target.name), suffix=".old", dir=self.target.parent)
            )
            os.replace(self.target, old / "previous")
        os.replace(self.path, self.target)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return self.target

    def discard(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.discard()  # after a commit there is nothing left to remove


@contextlib.contextmanager
def atomic_directory(path, owned):
    """Yield a temporary folder beside `path` that replaces it when the block ends without an
    error (StagedDirectory)."""
    with StagedDirectory(path, owned) as staged:
        yield staged.path
        staged.commit()


def _prefix(name: str) -> str:
    return f".{name}.{os.getpid()}-"


def remove_stale_temporaries(folder, name: str, suffix: str) -> list:
    """Remove the temporaries `.{name}.{pid}-*{suffix}` in `folder` whose writing process is no
    longer running (a killed run's leftovers); returns what was removed."""
    removed = []
    start = f".{name}."
    for entry in Path(folder).glob(f".{glob.escape(name)}.*-*{glob.escape(suffix)}"):
        pid = entry.name[len(start) :].split("-", 1)[0]
        if not pid.isdigit() or process_running(int(pid)):
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)
        removed.append(entry)
    return removed


def process_running(pid: int) -> bool:
    """Whether a process with this pid exists (True for another user's, and for a number that
    is no pid at all: callers leave alone what such a process may own)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True  # another user's process, or no pid at all: leave the file alone
    return True


def _current_umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask
