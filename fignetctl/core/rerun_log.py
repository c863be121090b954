"""Rerun recordings (.rrd): the one place that imports rerun.

    with recording("scene/pipeline.rrd") as (rr, rec):
        rec.log("world/points", rr.Points3D(points))

writes the file atomically (a temporary file beside it, renamed when the block ends without an
error). Every recording has application id "fignetctl" and recording id $FIGNETCTL_RECORDING_ID,
else the absolute path of the file's folder, so the recordings a scene's stages write into one
folder open in the viewer as one recording.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from fignetctl.core.atomic import atomic_path
from fignetctl.errors import FignetError

RECORDING_ID_ENV = "FIGNETCTL_RECORDING_ID"


def import_rerun():
    """The rerun module, or a FignetError that says how to install it."""
    try:
        import rerun
    except ImportError:
        raise FignetError("logging to rerun needs rerun-sdk: pip install rerun-sdk") from None
    return rerun


def recording_stream(path_rrd):
    """A rerun RecordingStream for a recording that will be written to `path_rrd` (or a
    temporary file beside it): the ids of the module docstring."""
    rr = import_rerun()
    recording_id = os.environ.get(RECORDING_ID_ENV) or str(Path(path_rrd).resolve().parent)
    return rr.RecordingStream("fignetctl", recording_id=recording_id)


@contextlib.contextmanager
def recording(path_rrd, blueprint=None):
    """(rr, rec): the rerun module and a stream saving to `path_rrd`, written atomically;
    `blueprint` (a rerun.blueprint.Blueprint) is the viewer's default layout."""
    rr = import_rerun()
    with atomic_path(Path(path_rrd), suffix=".rrd") as tmp:
        rec = recording_stream(tmp)
        if blueprint is None:
            rec.save(tmp)
        else:
            rec.save(tmp, default_blueprint=blueprint)
        try:
            yield rr, rec
            rec.flush()
        finally:
            rec.disconnect()
