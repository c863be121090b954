"""Read an HDF5 file in a forked child process, so that damage that crashes or hangs the HDF5
C library (a segmentation fault on a corrupt datatype message, an endless loop in a corrupt
global heap) ends in a FormatError instead of taking the command down with it.

The child does the whole read and hands the result back through a pipe, so the cost is one
fork and one copy of the arrays, not a second read. Where `fork` is not available the read
runs in this process, unguarded.
"""

from __future__ import annotations

import gc
import multiprocessing
from pathlib import Path

from fignetctl.errors import FormatError

BASE_TIMEOUT_S = 60.0
TIMEOUT_S_PER_MB = 2.0


def read_guarded(reader, path, *args):
    """reader(path, *args) run in a forked child; FormatError if the child crashes or hangs."""
    if "fork" not in multiprocessing.get_all_start_methods():
        return reader(path, *args)
    path = Path(path)
    context = multiprocessing.get_context("fork")
    receiving, sending = context.Pipe(duplex=False)
    child = context.Process(target=_run_child, args=(sending, reader, path, args), daemon=True)
    # The child must not collect the parent's garbage: a finalizer there (a video decoder's
    # release, say) can wait for threads that fork did not copy, and hang the read. Objects
    # frozen before the fork are left alone by the child's collector.
    gc.collect()
    gc.freeze()
    try:
        child.start()
    finally:
        gc.unfreeze()
    sending.close()
    timeout = BASE_TIMEOUT_S + TIMEOUT_S_PER_MB * path.stat().st_size / 1e6
    try:
        if not receiving.poll(timeout):
            raise FormatError(
                f"{path}: not a readable HDF5 file (the HDF5 library hung reading it; the file is damaged)"
            )
        status, value = receiving.recv()
    except EOFError:
        raise FormatError(
            f"{path}: not a readable HDF5 file (the HDF5 library crashed reading it; the file is damaged)"
        ) from None
    finally:
        receiving.close()
        if child.is_alive():
            child.kill()
        child.join()
    if status == "error":
        raise FormatError(value)
    return value


def _run_child(sending, reader, path, args):
    import faulthandler

    faulthandler.disable()  # a crash here is expected damage, reported by the parent in one line
    try:
        result = ("ok", reader(path, *args))
    except FormatError as error:
        result = ("error", str(error))
    except BaseException as error:  # reported in the parent; never a traceback from the child
        result = (
            "error",
            f"{path}: not readable ({type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''})",
        )
    try:
        sending.send(result)
    except Exception as error:  # a value that cannot cross the pipe: a reader's bug, said in one line
        sending.send(
            ("error", f"{path}: not readable (its content cannot be returned: {type(error).__name__})")
        )
    sending.close()
