"""train: a learned simulator, FIGNet* (or FIGNet), trained on a trajectory file, resumably."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from fignetctl.core.rerun_log import DEFAULT_VIEWER
from fignetctl.errors import SettingError
from fignetctl.stages import check, device_setting, no_progress, resolve_device, setting, to_stderr

TIME_LIMIT_EXIT = 75
"""`train`'s exit code when --time-limit stopped it (sysexits' EX_TEMPFAIL: not finished, run again)."""


@dataclasses.dataclass(frozen=True)
class Settings:
    model: str = setting(
        "fignet-star", "FIGNet* (no surface-mesh edges) or FIGNet.", choices=("fignet-star", "fignet")
    )
    size: str = setting(
        "small",
        "Network size preset (paper: latent 128, 10 message-passing steps).",
        choices=("tiny", "small", "paper"),
    )
    message_passing_steps: int | None = setting(
        None,
        "Processor blocks, in place of the --size's (tiny 2, small 5, paper 10). With --init-from a "
        "model of fewer blocks, its blocks come first and the added ones start as identity "
        "(docs/training-record.md).",
        low=1,
        high=64,
    )
    mlp_hidden_size: int | None = setting(
        None,
        "Width of every MLP hidden layer, in place of the --size's (tiny 32, small 64, paper 128). With "
        "--init-from a model of narrower ones, its units keep their weights and the added units start "
        "with zero outgoing weights, so the run starts from its predictions (docs/training-record.md).",
        low=1,
        high=4096,
    )
    added_blocks_learning_rate_scale: float = setting(
        1.0,
        "With --init-from a model of fewer blocks than --message-passing-steps: the added blocks' "
        "learning rate as a multiple of --learning-rate (they start as identity and grow from there).",
        low=0,
        low_open=True,
    )
    collision_radius: float | None = setting(
        None, "Face-face edge radius in metres.  [default: 0.2]", low=0, low_open=True
    )
    max_faces: int = setting(
        256,
        "Decimate each moving object's mesh to at most this many faces (static meshes stay whole).",
        low=4,
        high=10**6,
    )
    decimation: str = setting(
        "closest",
        "closest: quadric decimation unless it moves the surface over 1 % of the object's size, then the "
        "nearer of it and a surface-preserving reduction; quadric: as the models before this option, "
        "which lost the movi-b mug's thin parts (docs/simulator.md).",
        choices=("closest", "quadric"),
    )
    max_static_edge: float = setting(
        0.0,
        "Subdivide static meshes (the floor) to edges no longer than this (m); 0 keeps them whole.",
        low=0,
    )
    max_vertex_offset: float = setting(
        1.0, "Clamp the face-face features' vertex offsets to this length (m); 0: no clamp.", low=0
    )
    state: str = setting(
        "velocities",
        "The model's input: frame t and recorded velocities, or frames t-1 and t (docs/simulator.md).",
        choices=("velocities", "positions"),
    )
    static_receivers: bool = setting(
        False, "Face-face edges into static faces too (as the models before this option)."
    )
    speculative: bool = setting(
        False, "Also pair moving faces with static ones up to a step ahead (docs/simulator.md)."
    )
    mass_feature: str = setting(
        "kg",
        "The nodes' mass feature: in kg, or its logarithm (a mass ratio becomes a difference).",
        choices=("kg", "log"),
    )
    contact_velocity: bool = setting(
        False,
        "Face-face edges also carry their closest points' relative velocity and its approach rate "
        "(docs/training-record.md).",
    )
    inertia: bool = setting(
        False,
        "Object nodes also carry their inertia tensor per unit mass in the world frame; from an "
        "--init-from model without it, its input weights start at zero (docs/training-record.md).",
    )
    free_motion: bool = setting(
        False,
        "The network predicts what contact changes of each object's free motion (gravity, constant "
        "spin), which is computed and added (velocity state; docs/simulator.md).",
    )
    noise: tuple[float, float] = setting(
        (0.003, 0.003),
        "Standard deviations of the per-object jitter on frame t's pose, translation (m) and rotation "
        "(rad); the velocity state's velocity gets the same, per frame (docs/simulator.md).",
        low=0,
        metavar="METRES RADIANS",
    )
    target_keeps_noise: bool = setting(
        True, "The target keeps frame t's noise, so resting objects stop (docs/simulator.md)."
    )
    undo_position_noise: float = setting(
        0.0,
        "With the noise kept, the fraction of frame t's pose noise the target position still "
        "undoes, velocity unchanged, so objects pushed into the floor are moved back (docs/training-record.md).",
        low=0,
        high=1,
        metavar="FRACTION",
    )
    frame_sampling: str = setting(
        "uniform",
        "Which frames the examples are: uniform, or motion (impact frames drawn more often, their "
        "loss weighted down to keep the uniform expectation; docs/training-record.md).",
        choices=("uniform", "motion"),
    )
    loss: str = setting(
        "mse",
        "Loss on the normalized accelerations; huber weighs rare contact spikes less.",
        choices=("mse", "huber"),
    )
    unroll: int = setting(
        1,
        "Steps the loss follows the model through: 1, or n up to 8 (its answer for the next frame "
        "is also the start of a second step, scored too, and so on; velocity state; "
        "docs/training-record.md).",
        low=1,
        high=8,
    )
    velocity_weight: float = setting(
        1.0,
        "Loss weight of the velocity columns against the position columns (velocity state): an "
        "error in the next velocity moves every later frame of a rollout (docs/training-record.md).",
        low=0,
        low_open=True,
        high=1e6,
    )
    calm_weight: float = setting(
        0.0,
        "Extra loss weight of the vertices the recording has in free fall or at rest (their loss "
        "weighs 1 + this): small errors there add up over a rollout (docs/training-record.md).",
        low=0,
        high=1e6,
    )
    rest_weight: float = setting(
        0.0,
        "Extra loss weight of the vertices the recording keeps at rest (or steady), on top of "
        "--calm-weight: a resting object given a small velocity must stop (docs/training-record.md).",
        low=0,
        high=1e6,
    )
    steps: int = setting(20000, "Total optimiser steps (a resumed run continues to this).", low=1, high=10**9)
    batch_size: int = setting(4, "Scenes per step.", low=1, high=4096)
    pushforward: int = setting(
        0,
        "Examples per batch whose frame t is the model's own prediction from t-1, so it learns from "
        "its rollouts' errors (docs/simulator.md); fewer than --batch-size.",
        low=0,
        high=4095,
    )
    pushforward_model: str | None = setting(
        None,
        "Start the --pushforward examples from this fixed model file's predictions instead of the "
        "trained model's; the --workers then build them with the others, so they scale with the "
        "workers (docs/simulator.md).",
        metavar="FILE",
    )
    learning_rate: tuple[float, float] = setting(
        (3e-4, 3e-5),
        "Adam's learning rate decays exponentially from INITIAL to FINAL over --steps (the paper's "
        "1e-3 -> 1e-4 fitted held-out data worse at batch 8: docs/simulator.md).",
        low=0,
        low_open=True,
        metavar="INITIAL FINAL",
    )
    workers: int = setting(
        1, "Processes that build the training graphs (0: build them here).", low=0, high=256
    )
    scene_cache: int = setting(
        4096,
        "Training scenes each process keeps made (about 0.3 MB each on movi-b); one not kept is made "
        "again from the file's arrays when drawn (a few ms). 0 keeps all.",
        low=0,
        high=10**9,
    )
    precision: str = setting(
        "auto",
        "Training arithmetic: bf16 mixed precision, fp32, or auto (bf16 where natively supported).",
        choices=("auto", "bf16", "fp32"),
    )
    checkpoint_every: int = setting(
        500, "Write --output (and --log-csv) every this many steps.", low=1, high=10**9
    )
    resume: bool = setting(False, "Continue the run saved in --output exactly where it stopped.")
    time_limit: float | None = setting(
        None,
        "Stop after this many minutes, checkpointed, with exit code 75 (0 under torchrun, which reports "
        "other codes as a crash); the same command with --resume (in place of any --init-from) goes on "
        "(chunks for a batch queue).",
        low=0,
        low_open=True,
        metavar="MINUTES",
    )
    seed: int = setting(0, "Random seed, 0 to 2**32 - 1.", low=0, high=2**32 - 1)
    device: str = device_setting()
    rerun_connect: str | None = setting(
        None,
        "Stream the loss per step to the rerun viewer at ADDR while training runs (a viewer started "
        f"with `rerun`: {DEFAULT_VIEWER}); a warning if none listens.",
        metavar="ADDR",
    )


def configs(settings: Settings, device: str = "cpu"):
    """The (SimulatorConfig, TrainingSettings) a new run of these settings starts with (the
    data's dt and gravity are added from the trajectory file)."""
    from fignetctl.core.model.training import TrainingSettings, resolve_precision, simulator_config_for

    simulator_config = simulator_config_for(
        settings.model,
        settings.size,
        settings.collision_radius,
        settings.max_faces,
        settings.max_static_edge or None,
        settings.max_vertex_offset or None,
        settings.speculative,
        settings.state,
        settings.static_receivers,
        settings.mass_feature == "log",
        settings.decimation,
        settings.contact_velocity,
        settings.free_motion,
        settings.message_passing_steps,
        settings.inertia,
        settings.mlp_hidden_size,
    )
    training_config = TrainingSettings(
        steps=settings.steps,
        batch_size=settings.batch_size,
        learning_rate_initial=settings.learning_rate[0],
        learning_rate_final=settings.learning_rate[1],
        loss=settings.loss,
        velocity_weight=settings.velocity_weight,
        unroll=settings.unroll,
        pushforward=settings.pushforward,
        pushforward_model=settings.pushforward_model or "",
        frame_sampling=settings.frame_sampling,
        calm_weight=settings.calm_weight,
        rest_weight=settings.rest_weight,
        noise_translation_std=settings.noise[0],
        noise_rotation_std=settings.noise[1],
        target_keeps_noise=settings.target_keeps_noise,
        position_noise_undone=settings.undo_position_noise,
        checkpoint_every=settings.checkpoint_every,
        seed=settings.seed,
        added_blocks_learning_rate_scale=settings.added_blocks_learning_rate_scale,
        precision=resolve_precision(settings.precision, device),
    )
    return simulator_config, training_config


def run(
    dataset,
    output,
    settings: Settings = Settings(),
    init_from=None,
    log_csv=None,
    rerun_path=None,
    overwrite=False,
    progress=None,
    report=None,
) -> dict:
    """Train on the trajectory file `dataset`, writing the model file `output` atomically every
    `checkpoint_every` steps (with the training data's hash); `resume` continues the run saved
    in `output`, `init_from` starts a new one from a model file's weights. `log_csv` gets step,
    loss and seconds at every checkpoint, `rerun_path` the loss curve; `settings.rerun_connect`
    streams the curve to the viewer there as training goes (a warning through `report`, stderr
    when None, if none listens). Data-parallel under torchrun: every rank trains, rank 0 writes and
    streams. `settings.time_limit` stops the run early, checkpointed (`stopped_early` in the
    summary, with the `message` to print and the `exit_code`). Returns the summary (output,
    steps, loss, rank, stopped_early, message, exit_code)."""
    from fignetctl.core.model.training import make_trainer, network_threads, write_loss_csv
    from fignetctl.core.rerun_log import live_recording, viewer_address
    from fignetctl.core.viz import log_scalar_step

    check(settings)
    if settings.rerun_connect is not None:
        viewer_address(settings.rerun_connect)  # a bad address is refused before training, not after
    if settings.pushforward >= settings.batch_size:
        raise SettingError(
            f"--pushforward {settings.pushforward}: give fewer than --batch-size ({settings.batch_size}); "
            "the others are ordinary examples"
        )
    if settings.pushforward_model and not settings.pushforward:
        raise SettingError(
            "--pushforward-model gives the pushforward examples' start: give --pushforward N too"
        )
    if settings.free_motion and settings.state != "velocities":
        raise SettingError(
            "--free-motion adds the free motion of each object's recorded velocity: give --state velocities"
        )
    if settings.resume and overwrite:
        raise SettingError("--resume continues --output, --overwrite replaces it: give one")
    if settings.resume and init_from:
        raise SettingError("--resume continues --output, --init-from starts a new run: give one")
    output, device = Path(output), resolve_device(settings.device)
    simulator_config, training_config = configs(settings, device)
    resume_from = output if settings.resume and output.exists() else None
    trainer = make_trainer(
        dataset,
        simulator_config,
        training_config,
        device,
        resume_from,
        init_from,
        settings.workers,
        settings.scene_cache or None,
    )
    address = settings.rerun_connect if trainer.rank == 0 else None
    with (
        network_threads(settings.workers, device),
        live_recording(address, rerun_path or output, report or to_stderr) as live,
        (progress or no_progress)(
            total=settings.steps,
            initial=trainer.step,
            unit="step",
            desc="train",
            disable=trainer.rank != 0 or None,
        ) as bar,
    ):

        def on_step(step, loss):
            bar.update(1)
            bar.set_postfix(loss=f"{loss:.4g}")
            if live:
                log_scalar_step(*live, "train", step, {"loss": loss})

        stopped = trainer.run(
            output,
            on_step=on_step,
            on_checkpoint=lambda: log_csv and trainer.rank == 0 and write_loss_csv(log_csv, trainer.history),
            time_limit=None if settings.time_limit is None else 60 * settings.time_limit,
        )
    if trainer.rank == 0 and rerun_path:
        from fignetctl.core.viz import log_scalars_to_rerun

        log_scalars_to_rerun(rerun_path, "train", {"loss": [(h["step"], h["loss"]) for h in trainer.history]})
    history = trainer.history
    message = None
    if stopped:
        resume = "--resume in place of --init-from" if init_from else "--resume"
        message = (
            f"train: stopped at the time limit after step {trainer.step} of {settings.steps}, checkpointed "
            f"in {output}; run the same command with {resume} to go on"
        )
    return {
        "output": str(output),
        "steps": trainer.step,
        "loss": history[-1]["loss"] if history else None,
        "rank": trainer.rank,
        "stopped_early": stopped,
        "message": message,
        # torchrun reports a process's other exit codes as a crash, with a traceback of its own
        "exit_code": TIME_LIMIT_EXIT if stopped and "TORCHELASTIC_RUN_ID" not in os.environ else 0,
    }
