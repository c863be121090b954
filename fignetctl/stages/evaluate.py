"""evaluate: the paper's metrics of a model against ground truth, with baselines, as json."""

from __future__ import annotations

import dataclasses

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
)


@dataclasses.dataclass(frozen=True)
class Settings:
    max_trajectories: int | None = setting(None, "Evaluate only the first N trajectories.", low=1, high=10**7)
    sleep: bool = sleep_setting(False)
    free_flight: bool = free_flight_setting(False)
    keep_out: bool = keep_out_setting(False)
    with_guards: bool = setting(
        False,
        "Also evaluate the model as `rollout` runs it (free flight, keep-out, sleeping): model_with_guards.",
    )
    ceilings: bool = setting(
        False, "Also evaluate PyBullet restarted every frame from a model's inputs (make-dataset DATA only)."
    )
    against: str | None = setting(
        None,
        "Also roll out this model file (or bundled model name), with its own turns and meshes, and "
        "compare the model with it trajectory by trajectory (comparison.against).",
        metavar="MODEL",
    )
    rotations: int | None = rotations_setting()
    max_faces: int | None = max_faces_setting()
    device: str = device_setting()


def run(data, output=None, settings: Settings = Settings(), model=None, progress=None) -> dict:
    """Roll out the model file (or bundled model name) `model` from frames 0-1 of every
    trajectory of the file `data` and compare (fignetctl.core.model.apply.evaluate_trajectories); the
    metrics, with the model's name and the inputs' hashes, are written to the json file
    `output` atomically when given, and returned."""

    from fignetctl.core.model.apply import evaluate_trajectories, load_model
    from fignetctl.core.provenance import INPUTS_KEY, stamp
    from fignetctl.core.trajectory import read_trajectories

    check(settings)
    device = resolve_device(settings.device)
    simulator = load_model(model, device, settings.rotations, settings.max_faces)
    against = None if settings.against is None else load_model(settings.against, device)
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
            against=against,
        )
    metrics = {"data": str(data), **metrics}
    metrics["model"] = str(model or "fignet-star-movi-b")
    metrics.update(stamp(data=data))
    metrics[INPUTS_KEY]["model"] = simulator.source_sha256
    if against is not None:
        metrics["against"] = settings.against
        metrics[INPUTS_KEY]["against"] = against.source_sha256
    if output is not None:
        from fignetctl.core.atomic import write_json

        write_json(output, metrics, indent=2)
    return metrics
