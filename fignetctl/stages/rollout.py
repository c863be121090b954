"""rollout: a scene simulated forward with a learned model, into a trajectory file."""

from __future__ import annotations

import dataclasses
import math

from fignetctl.errors import FignetError, SettingError
from fignetctl.stages import (
    check,
    device_setting,
    free_flight_setting,
    keep_out_setting,
    max_faces_setting,
    no_progress,
    resolve_device,
    rotations_setting,
    setting,
    sleep_setting,
    to_stderr,
    write_summary,
)


@dataclasses.dataclass(frozen=True)
class Settings:
    steps: int = setting(100, "Frames to predict after the scene's first two.", low=1, high=10**6)
    trajectory: str | None = setting(None, "Which trajectory of SCENE.  [default: the first]")
    sim_scale: float | str = setting(
        "auto",
        "Simulate the scene scaled by this factor, or 'auto': to the model's sizes if outside them.",
        low=1e-3,
        high=1e3,
    )
    sleep: bool = sleep_setting(True)
    free_flight: bool = free_flight_setting(True)
    keep_out: bool = keep_out_setting(True)
    rotations: int | None = rotations_setting()
    max_faces: int | None = max_faces_setting()
    device: str = device_setting()


def parse_sim_scale(value) -> float | str:
    """'auto', or a scale between 0.001 and 1000 (a number or its text); FignetError otherwise."""
    if isinstance(value, str) and value.strip().lower() == "auto":
        return "auto"
    try:
        scale = float(value)
    except (TypeError, ValueError):
        scale = float("nan")
    if not (math.isfinite(scale) and 1e-3 <= scale <= 1e3):
        raise SettingError(f"{value!r} is not 'auto' or a scale between 0.001 and 1000")
    return scale


def run(
    scene,
    output,
    settings: Settings = Settings(),
    model=None,
    rerun_path=None,
    json_path=None,
    progress=None,
    report=None,
) -> dict:
    """Predict `settings.steps` frames after the first two of the trajectory file `scene` with the
    model file (or bundled model name) `model`, and write them to `output` atomically, with
    the model's and the scene's hashes. `report` (default: stderr) gets a note when the scene is
    simulated at another scale or under the model's gravity (froude.py). A rollout that goes wrong still writes the frames before the failure, then
    raises a FignetError naming the step and object. Returns the summary (also the --json)."""
    from fignetctl.core.model.apply import load_model, rollout_trajectory
    from fignetctl.core.model.rollout import RolloutError
    from fignetctl.core.provenance import INPUTS_KEY, as_strings, file_sha256, from_strings, stamp
    from fignetctl.core.trajectory import read_trajectories

    check(settings)
    sim_scale = parse_sim_scale(settings.sim_scale)
    simulator = load_model(model, resolve_device(settings.device), settings.rotations, settings.max_faces)
    data = read_trajectories(scene, None if settings.trajectory is None else [settings.trajectory])
    with (progress or no_progress)(total=settings.steps, unit="step", desc="rollout") as bar:
        try:
            result = rollout_trajectory(
                simulator,
                data,
                settings.steps,
                on_step=lambda _: bar.update(1),
                sim_scale=sim_scale,
                sleep=settings.sleep,
                free_flight=settings.free_flight,
                keep_out=settings.keep_out,
                where=str(scene),
            )
            error = None
        except RolloutError as failure:
            result, error = failure.partial_file, failure
    inputs = {"scene": file_sha256(scene), "model": getattr(simulator, "source_sha256", None)}
    result.attrs.update(as_strings({**stamp(), INPUTS_KEY: {k: v for k, v in inputs.items() if v}}))
    _write(result, output, rerun_path)
    scale = float(result.attrs["sim_scale"])
    if scale != 1.0:
        (report or to_stderr)(
            f"simulated at {scale:.4g}x its size, as the model knows objects of that size; "
            f"frames {1000 * result.dt:.3g} ms apart (--sim-scale 1 to simulate it as it is)"
        )
    ratio = float(result.attrs["gravity_ratio"])
    if ratio != 1.0:
        strength = math.hypot(*result.gravity)
        (report or to_stderr)(
            f"simulated under the gravity the model learned ({strength / ratio:.4g} m/s²) in the time that "
            f"makes it the scene's ({strength:.4g} m/s²): frames {1000 * result.dt:.3g} ms apart"
        )
    trajectory = next(iter(result.trajectories.values()))
    summary = {
        "output": str(output),
        "steps": trajectory.num_frames - 2,
        "sim_scale": scale,
        "frame_seconds": float(result.dt),
        "final_positions": trajectory.positions[-1][~trajectory.static],
        "error": None if error is None else str(error),
    }
    write_summary(json_path, summary, from_strings(result.attrs))
    if error is not None:
        raise FignetError(f"{error} (written to {output})")
    return summary


def _write(result, path, rerun_path):
    from fignetctl.core.trajectory import write_trajectories

    write_trajectories(path, result)
    if rerun_path:
        from fignetctl.core.viz import log_trajectory_to_rerun

        log_trajectory_to_rerun(result, next(iter(result.trajectories)), rerun_path)
