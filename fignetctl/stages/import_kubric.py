"""import-kubric: Kubric scenes (each a MOVi-style worker's metadata.json) as one trajectory file."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from fignetctl.stages import check, setting


@dataclasses.dataclass(frozen=True)
class Settings:
    floor_friction: float = setting(0.3, "Friction of the static floor.", low=0, high=10)
    floor_restitution: float = setting(0.5, "Restitution of the static floor.", low=0, high=1)
    floor_size: float = setting(20.0, "Side of the floor square (m).", low=0.01, high=1e4)


def run(metadata, assets, output, settings: Settings = Settings()) -> dict:
    """Convert the scenes `metadata` (metadata.json files), their collision meshes in the folder
    `assets`, into the trajectory file `output` with its provenance; returns the summary
    (scenes, objects, frames per second) with a one-line `message`."""
    from fignetctl.core.kubric import kubric_file
    from fignetctl.core.provenance import as_strings, stamp
    from fignetctl.core.trajectory import write_trajectories

    check(settings)
    metadata = list(metadata)
    data = kubric_file(
        metadata, assets, settings.floor_friction, settings.floor_restitution, settings.floor_size / 2
    )
    data.attrs.update(
        as_strings(stamp(**{f"metadata_{i}": p for i, p in enumerate(metadata)}, assets=assets))
    )
    write_trajectories(Path(output), data)
    objects = sum(t.num_objects - 1 for t in data.trajectories.values())
    summary = {"output": str(output), "scenes": len(data.trajectories), "objects": objects}
    summary["frames_per_second"] = 1 / data.dt
    summary["message"] = f"{summary['scenes']} scenes, {objects} objects, {1 / data.dt:g} frames/s"
    return summary
