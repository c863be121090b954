"""Read rerun recordings (.rrd) back with the SDK, for the tests of the commands that write them.

    recording = read_recording("out/fit.rrd")
    recording.rows("fit-nerf/loss")            # rows logged on its timelines (static ones apart)
    recording.times("world/objects/01_box", "frame")  # the distinct times, sorted
    recording.entities_under("world/cameras")  # the entities below a path

Several files whose recording ids agree merge into one Recording (`read_recordings`), as the
viewer shows them.
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np


@dataclasses.dataclass
class Entity:
    static: bool = False
    rows: int = 0
    components: set = dataclasses.field(default_factory=set)
    timelines: dict = dataclasses.field(default_factory=dict)  # name -> set of times (int; ns for durations)


@dataclasses.dataclass
class Recording:
    application_id: str
    recording_ids: set
    entities: dict  # "a/b" (no leading slash) -> Entity

    @property
    def recording_id(self) -> str:
        assert len(self.recording_ids) == 1, self.recording_ids
        return next(iter(self.recording_ids))

    def rows(self, entity: str) -> int:
        return self.entities[entity].rows

    def times(self, entity: str, timeline: str) -> list:
        return sorted(self.entities[entity].timelines.get(timeline, ()))

    def entities_under(self, root: str) -> list:
        root = root.strip("/")
        return sorted(e for e in self.entities if e == root or e.startswith(root + "/"))

    def components(self, entity: str) -> set:
        return self.entities[entity].components


def read_recording(path) -> Recording:
    """The one recording store in the .rrd at `path` (the blueprint aside), entity by entity."""
    from rerun.chunk import RrdReader

    with warnings.catch_warnings():  # a file a viewer saved (rerun --save) has no footer
        warnings.simplefilter("ignore")
        reader = RrdReader(Path(path))
        stores = reader.recordings()
        assert len(stores) == 1, f"{path}: {len(stores)} recording stores"
        chunks = list(reader.stream(store=stores[0]))
    entities = {}
    for chunk in chunks:
        name = chunk.entity_path.strip("/")
        if name.startswith("__"):  # recording properties
            continue
        entity = entities.setdefault(name, Entity())
        batch = chunk.to_record_batch()
        timelines = set(chunk.timeline_names)
        entity.components |= {
            c for c in batch.schema.names if c not in timelines and not c.startswith("rerun.")
        }
        if chunk.is_static:
            entity.static = True
            continue
        entity.rows += chunk.num_rows
        for timeline in timelines:
            values = np.asarray(batch.column(timeline).cast("int64"))
            entity.timelines.setdefault(timeline, set()).update(values.tolist())
    return Recording(stores[0].application_id, {stores[0].recording_id}, entities)


def read_recordings(paths) -> Recording:
    """Several .rrd files as the viewer opens them together: their entities merged (rows add
    up), with every recording id they carry."""
    recordings = [read_recording(p) for p in paths]
    merged = Recording(recordings[0].application_id, set().union(*(r.recording_ids for r in recordings)), {})
    for recording in recordings:
        assert recording.application_id == merged.application_id
        for name, entity in recording.entities.items():
            into = merged.entities.setdefault(name, Entity())
            into.static |= entity.static
            into.rows += entity.rows
            into.components |= entity.components
            for timeline, values in entity.timelines.items():
                into.timelines.setdefault(timeline, set()).update(values)
    return merged


def rerun_executable():
    """The rerun CLI installed with the SDK (beside this Python), or on PATH; None if neither."""
    import shutil
    import sys

    beside_python = Path(sys.executable).parent / "rerun"
    return str(beside_python) if beside_python.exists() else shutil.which("rerun")


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def dead_address() -> str:
    """A viewer address where nothing listens."""
    return f"rerun+http://127.0.0.1:{free_port()}/proxy"


class SavingViewer:
    """`rerun --port P --save FILE`: a viewer's gRPC server that writes what SDKs stream to it
    into FILE (read it with `read_recording` after `stop`). Use as a context manager."""

    def __init__(self, path):
        self.path, self.port = Path(path), free_port()
        self.address = f"rerun+http://127.0.0.1:{self.port}/proxy"

    def __enter__(self):
        import subprocess
        import time

        from fignetctl.core.rerun_log import viewer_listens

        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.process = subprocess.Popen(
            [rerun_executable(), "--port", str(self.port), "--save", str(self.path)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,  # its own process group: the wrapper and the server it starts
        )
        deadline = time.monotonic() + 30
        while not viewer_listens(self.address, timeout=0.5):
            assert self.process.poll() is None and time.monotonic() < deadline, "rerun did not start"
            time.sleep(0.1)
        return self

    def stop(self) -> None:
        """Stop the server (as Ctrl-C does) once what it received is on disk."""
        import os
        import signal
        import subprocess
        import time

        if self.process.poll() is not None:
            return
        size, deadline = -1, time.monotonic() + 10
        while time.monotonic() < deadline:  # the file stops growing
            now = self.path.stat().st_size if self.path.exists() else 0
            if now == size and now > 0:
                break
            size = now
            time.sleep(0.5)
        group = os.getpgid(self.process.pid)
        os.killpg(group, signal.SIGINT)
        try:
            self.process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(group, signal.SIGKILL)
            self.process.wait()

    def __exit__(self, *exc):
        self.stop()
