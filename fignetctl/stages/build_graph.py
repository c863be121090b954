"""build-graph: extracted meshes + physical properties + a drop -> the 2-frame scene `rollout` simulates."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from fignetctl.core.scene_building import ACTIVE, PASSIVE
from fignetctl.stages import check, setting, write_summary


@dataclasses.dataclass(frozen=True)
class Settings:
    drop_height: float = setting(
        0.1, "Start this far above the object's rest position (world units).", low=0, high=1000
    )
    delta_z: float = setting(
        0.01, "Δz: the history frame is this much higher (fall speed Δz per frame).", low=0, high=1000
    )
    start: tuple[float, float, float] | None = setting(
        None, "Start position of the object's origin instead of --drop-height.", metavar="X,Y,Z"
    )
    velocity: tuple[float, float, float] | None = setting(
        None, "Start velocity (world units / s) instead of Δz per frame.", metavar="VX,VY,VZ"
    )
    duplicate: bool = setting(
        False, "Simulate a copy at the start; the original stays in place as a static object."
    )
    active_mass: float = setting(ACTIVE.mass, "Mass of the active object.", low=1e-9, high=1e9)
    active_friction: float = setting(ACTIVE.friction, "Friction of the active object.", low=0, high=10)
    active_restitution: float = setting(
        ACTIVE.restitution, "Restitution of the active object.", low=0, high=1
    )
    passive_friction: float = setting(PASSIVE.friction, "Friction of the passive object.", low=0, high=10)
    passive_restitution: float = setting(
        PASSIVE.restitution, "Restitution of the passive object.", low=0, high=1
    )
    dt: float = setting(1 / 30, "Seconds between frames; the bundled models' is 1/30.", low=0, low_open=True)
    gravity: float = setting(
        9.81,
        "Gravity (m/s², along -z). rollout simulates a scene under another gravity than its model learned "
        "(the bundled models: 10) in the time that makes it the same motion.",
        low=0,
        low_open=True,
        high=1000,
    )


def run(
    volume_path,
    output,
    settings: Settings = Settings(),
    object_path=None,
    environment_path=None,
    json_path=None,
) -> dict:
    """Build the scene of the object (active) and the environment (passive) of the volume.npz
    `volume_path` (their meshes beside it unless `object_path`, `environment_path`), with the
    history a drop (or `settings.start` and `settings.velocity`), into the trajectory file
    `output`; the summary goes to `json_path` too. Returns the summary with a one-line `message`."""
    from fignetctl.core.obj import load_obj
    from fignetctl.core.provenance import as_strings, stamp
    from fignetctl.core.scene_building import Properties, build_scene, drop_history
    from fignetctl.core.trajectory import write_trajectories
    from fignetctl.core.volume import read_volume

    check(settings)
    volume = read_volume(volume_path)
    folder = Path(volume_path).parent
    obj = load_obj(object_path or folder / volume.object_mesh)
    environment = load_obj(environment_path or folder / volume.environment_mesh)
    s = settings  # short, for the many fields below
    positions = drop_history(volume.origin, s.drop_height, s.delta_z, s.start, s.velocity, s.dt)
    scene = build_scene(
        (obj.vertices, obj.faces),
        (environment.vertices, environment.faces),
        volume.origin,
        positions,
        Properties(s.active_mass, s.active_friction, s.active_restitution),
        Properties(0.0, s.passive_friction, s.passive_restitution),
        s.duplicate,
        volume.environment_origin,
        s.dt,
        (0.0, 0.0, -s.gravity),
    )
    provenance = stamp(
        volume=volume_path,
        object=object_path or folder / volume.object_mesh,
        environment=environment_path or folder / volume.environment_mesh,
    )
    scene.attrs.update(as_strings(provenance))
    write_trajectories(Path(output), scene)
    summary = {
        "output": str(output),
        "object_faces": len(obj.faces),
        "environment_faces": len(environment.faces),
        "start": positions[1],
        "history": positions[0],
    }
    write_summary(json_path, summary, provenance)
    summary["message"] = (
        f"scene: {len(obj.faces)} + {len(environment.faces)} faces, start {positions[1].round(4).tolist()}"
    )
    return summary
