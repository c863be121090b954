"""Rerun recordings (.rrd): the one place that imports rerun.

    with recording("scene/pipeline.rrd") as (rr, rec):
        rec.log("world/points", rr.Points3D(points))

writes the file atomically (a temporary file beside it, renamed when the block ends without an
error). Every recording has application id "fignetctl" and recording id $FIGNETCTL_RECORDING_ID,
else the absolute path of the file's folder, so the recordings a scene's stages write into one
folder open in the viewer as one recording.

    with live_recording("rerun+http://127.0.0.1:9876/proxy", "scene/nerf.pt", report) as live:
        if live:
            rr, rec = live
            rec.log("fit-nerf/loss", rr.Scalars(loss))

streams to a running viewer while a command runs (same ids, so the viewer shows the live data
and the .rrd written at the end as one recording); `live` is None, after one warning through
`report`, when no viewer listens there.
"""

from __future__ import annotations

import contextlib
import os
import socket
from pathlib import Path
from urllib.parse import urlsplit

from fignetctl.core.atomic import atomic_path
from fignetctl.errors import FignetError, SettingError

RECORDING_ID_ENV = "FIGNETCTL_RECORDING_ID"
DEFAULT_VIEWER = "rerun+http://127.0.0.1:9876/proxy"
"""Where a viewer started with `rerun` listens for SDKs (rerun's default gRPC address)."""
PROBE_SECONDS = 2.0
"""How long to wait for a viewer to accept a connection before going on without it."""
_DEFAULT_PORTS = {"rerun": 443, "rerun+https": 443, "rerun+http": 80}


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
    return rr.RecordingStream("fignetctl", recording_id=recording_id(path_rrd))


def recording_id(path) -> str:
    """$FIGNETCTL_RECORDING_ID, else the absolute path of the folder that holds `path`."""
    return os.environ.get(RECORDING_ID_ENV) or str(Path(path).resolve().parent)


def viewer_address(address: str) -> tuple:
    """(host, port) of a viewer's gRPC address such as DEFAULT_VIEWER; refused in one line
    when it is not of that form."""
    parts = urlsplit(str(address))
    try:
        port = parts.port
    except ValueError:
        port = -1
    if parts.scheme not in _DEFAULT_PORTS or not parts.hostname or parts.path != "/proxy" or port == -1:
        raise SettingError(
            f"`rerun_connect` {address!r}: give a viewer's gRPC address such as {DEFAULT_VIEWER}"
        )
    return parts.hostname, port or _DEFAULT_PORTS[parts.scheme]


def viewer_listens(address: str, timeout: float = PROBE_SECONDS) -> bool:
    """Whether something accepts a TCP connection at the viewer address `address`."""
    try:
        with socket.create_connection(viewer_address(address), timeout=timeout):
            return True
    except OSError:
        return False


@contextlib.contextmanager
def live_recording(address, near_path, report=None):
    """(rr, rec): the rerun module and a stream to the viewer at `address` (see the module
    docstring), with the recording id of a recording written beside `near_path`; None when
    `address` is None, or (after one line through `report`) when no viewer listens there. A
    viewer that goes away during the run never stops it (at most a warning at the end)."""
    if address is None:
        yield None
        return
    viewer_address(address)
    rr = import_rerun()
    if not viewer_listens(address):
        _say(report, f"warning: no rerun viewer listens at {address}; going on without live viewing")
        yield None
        return
    rec = rr.RecordingStream("fignetctl", recording_id=recording_id(near_path))
    rec.connect_grpc(address)
    try:
        yield rr, rec
    finally:
        try:
            rec.flush(timeout_sec=PROBE_SECONDS)
        except Exception as error:  # the SDK raises RuntimeError when the viewer went away
            why = (str(error).splitlines() or [type(error).__name__])[0]
            _say(report, f"warning: the rerun viewer at {address} stopped taking data ({why})")
        rec.disconnect()


def _say(report, line: str) -> None:
    if report is None:
        import sys

        print(line, file=sys.stderr, flush=True)
    else:
        report(line)


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
