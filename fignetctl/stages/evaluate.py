"""evaluate: the paper's metrics of a model against ground truth, with baselines, as json."""

from __future__ import annotations

import dataclasses

from fignetctl.stages import check, no_progress, resolve_device, setting


@dataclasses.dataclass(frozen=True)
class Settings:
    max_trajectories: int | None = setting(None, "Evaluate only the first N trajectories.", low=1, high=10**7)
    sleep: bool = setting(
        False, "Stop simulating objects at rest until something comes near (docs/simulator.md)."
    )
    free_flight: bool = setting(
        False, "Move objects that touch nothing in exact free flight, not by the network (docs/simulator.md)."
    )
    keep_out: bool = setting(
        False, "Move an object that passed into static geometry back out after each step (docs/simulator.md)."
    )
    with_guards: bool = setting(
        False,
        "Also evaluate the model as `rollout` runs it (free flight, keep-out, sleeping): model_with_guards.",
    )
    ceilings: bool = setting(
        False, "Also evaluate PyBullet restarted every frame from a model's inputs (make-dataset DATA only)."
    )
    rotations: int | None = setting(
        None,
        "Average the network over this many equal turns of the scene about gravity: exactly equivariant to them, at that many times the network's work (docs/simulator.md).  [default: the model file's, 1 unless it records more]",
        low=1,
        high=64,
    )
    max_faces: int | None = setting(
        None,
        "Decimate each moving object's mesh to at most this many faces; 0 keeps them whole: finer meshes cost time and gain accuracy (docs/accuracy-vs-time.md).  [default: the model file's, 256 for the bundled models]",
        low=0,
        high=10**6,
    )
    device: str = setting(
        "auto", "Torch device; 'auto' uses CUDA when available.", choices=("cpu", "cuda", "auto")
    )


def run(data, output=None, settings: Settings = Settings(), model=None, progress=None) -> dict:
    """Roll out the model file (or bundled model name) `model` from frames 0-1 of every
    trajectory of the file `data` and compare (fignetctl.core.model.apply.evaluate_trajectories); the
    metrics, with the model's name and the inputs' hashes, are written to the json file
    `output` atomically when given, and returned."""

    from fignetctl.core.model.apply import evaluate_trajectories, load_model
    from fignetctl.core.provenance import INPUTS_KEY, stamp
    from fignetctl.core.trajectory import read_trajectories

    check(settings)
    simulator = load_model(model, resolve_device(settings.device), settings.rotations, settings.max_faces)
    trajectories = read_trajectories(data)
    total = len(list(trajectories.trajectories)[: settings.max_trajectories])
    with (progress or no_progress)(total=total, unit="trajectory", desc="evaluate") as bar:
        metrics = evaluate_trajectories(
            simulator,
            trajectories,
            settings.max_trajectories,
            on_scene=lambda _: bar.update(1),
            sleep=settings.sleep,
            free_flight=settings.free_flight,
            keep_out=settings.keep_out,
            with_guards=settings.with_guards,
            ceilings=settings.ceilings,
            where=str(data),
        )
    metrics = {"data": str(data), **metrics}
    metrics["model"] = str(model or "fignet-star-movi-b")
    metrics.update(stamp(data=data))
    metrics[INPUTS_KEY]["model"] = simulator.source_sha256
    if output is not None:
        from fignetctl.core.atomic import write_json

        write_json(output, metrics, indent=2)
    return metrics
