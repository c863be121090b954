"""`fignetctl train`: train FIGNet* (or FIGNet) on a trajectory file, resumably."""

import click

from fignetctl.commands import options


@click.command("train")
@click.argument("dataset", type=click.Path(dir_okay=False))
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False),
    required=True,
    help="Model file (.pt) to write; checkpointed while training.",
)
@click.option(
    "--model",
    "architecture",
    type=click.Choice(["fignet-star", "fignet"]),
    default="fignet-star",
    show_default=True,
    help="FIGNet* (no surface-mesh edges) or FIGNet.",
)
@click.option(
    "--size",
    type=click.Choice(["tiny", "small", "paper"]),
    default="small",
    show_default=True,
    help="Network size preset (paper: latent 128, 10 message-passing steps).",
)
@click.option(
    "--collision-radius",
    type=options.FiniteFloatRange(min=0, min_open=True),
    default=None,
    help="Face-face edge radius in metres.  [default: 0.2]",
)
@click.option(
    "--max-faces",
    type=click.IntRange(min=4, max=10**6),
    default=256,
    show_default=True,
    help="Decimate each moving object's mesh to at most this many faces for the graph (static meshes stay whole).",
)
@click.option(
    "--max-static-edge",
    type=options.FiniteFloatRange(min=0),
    default=0.0,
    show_default=True,
    help="Subdivide static meshes (the floor) until no edge is longer than this (m); 0 keeps them whole.",
)
@click.option(
    "--max-vertex-offset",
    type=options.FiniteFloatRange(min=0),
    default=1.0,
    show_default=True,
    help="Clamp the face-face features' vertex offsets to this length (m), so huge floor triangles look like near ones; 0: no clamp.",
)
@click.option(
    "--state",
    type=click.Choice(["velocities", "positions"]),
    default="velocities",
    show_default=True,
    help="What the model is given: frame t and each object's instantaneous velocity (needs a dataset with recorded velocities), or frames t-1 and t (FIGNet's finite-difference velocity).",
)
@click.option(
    "--static-receivers/--no-static-receivers",
    default=False,
    show_default=True,
    help="Face-face edges into static faces too (the models before this option); without, static nodes send but do not aggregate (28% fewer face-face edges).",
)
@click.option(
    "--speculative/--no-speculative",
    default=False,
    show_default=True,
    help="Also pair a moving object's faces with static faces out to the radius plus its displacement over the step (at most the radius), so a fast object sees the floor one step ahead.",
)
@click.option(
    "--init-from",
    type=click.Path(dir_okay=False),
    default=None,
    help="Start from this model file's weights and normalizer statistics (fine-tuning) instead of random weights; the settings given here must give the same network.",
)
@click.option(
    "--target-keeps-noise/--no-target-keeps-noise",
    default=True,
    show_default=True,
    help="The target next position carries frame t's noise, so the network learns to undo velocity noise only (resting objects stop); --no-...: it undoes position noise too, which makes resting objects oscillate (the runs before this option).",
)
@click.option(
    "--loss",
    type=click.Choice(["mse", "huber"]),
    default="mse",
    show_default=True,
    help="Loss on the normalized accelerations; huber weighs rare contact spikes less.",
)
@click.option(
    "--steps",
    type=click.IntRange(min=1, max=10**9),
    default=20000,
    show_default=True,
    help="Total optimiser steps (a resumed run continues to this).",
)
@click.option(
    "--batch-size",
    type=click.IntRange(min=1, max=4096),
    default=4,
    show_default=True,
    help="Scenes per step.",
)
@click.option(
    "--learning-rate",
    type=(options.FiniteFloatRange(min=0, min_open=True), options.FiniteFloatRange(min=0, min_open=True)),
    default=(1e-3, 1e-4),
    show_default=True,
    metavar="INITIAL FINAL",
    help="Adam's learning rate decays exponentially from INITIAL to FINAL over --steps (the paper: 1e-3 1e-4); a fine-tuning may start lower.",
)
@click.option(
    "--workers",
    type=click.IntRange(min=0, max=256),
    default=1,
    show_default=True,
    help="Processes that build the training graphs while this one runs the network (0: build them here).",
)
@click.option(
    "--precision",
    type=click.Choice(["auto", "bf16", "fp32"]),
    default="auto",
    show_default=True,
    help="The network's arithmetic in training: bf16 mixed precision, fp32, or auto (bf16 where the processor or GPU has native bfloat16).",
)
@click.option("--checkpoint-every", type=click.IntRange(min=1, max=10**9), default=500, show_default=True)
@click.option("--resume", is_flag=True, help="Continue the run saved in --output exactly where it stopped.")
@click.option(
    "--log-csv",
    type=click.Path(dir_okay=False),
    default=None,
    help="Also write step, loss, seconds to this CSV (at every checkpoint).",
)
@options.seed_option
@options.device_option
@options.rerun_option
@options.overwrite_option
def train(
    dataset,
    output,
    architecture,
    size,
    collision_radius,
    max_faces,
    max_static_edge,
    max_vertex_offset,
    state,
    static_receivers,
    speculative,
    init_from,
    target_keeps_noise,
    loss,
    steps,
    batch_size,
    learning_rate,
    workers,
    precision,
    checkpoint_every,
    resume,
    log_csv,
    seed,
    device,
    rerun_path,
    overwrite,
):
    """Train a learned simulator on DATASET (a trajectory file from make-dataset).

    Adam with the learning rate decaying exponentially (--learning-rate, 1e-3 -> 1e-4) over --steps, noise on
    the input history, MSE (or --loss huber) on normalized accelerations of the dynamic mesh nodes. The model
    file is written atomically every --checkpoint-every steps; --resume continues from it
    with the same weights an uninterrupted run would reach. Runs data-parallel under
    torchrun (see docs/simulator.md).

    \b
    Example:
      fignetctl make-dataset --preset movi-b -n 200 --seed 1 -o train.h5
      fignetctl train train.h5 -o model.pt --steps 20000 --workers 1
      fignetctl train train.h5 -o model.pt --steps 20000 --resume   # after an interruption
      fignetctl train train.h5 -o tuned.pt --steps 3000 --init-from model.pt --learning-rate 2e-4 2e-5
    """
    from fignetctl.core.model.training import (
        TrainingConfig,
        make_trainer,
        resolve_precision,
        simulator_config_for,
        write_loss_csv,
    )

    if resume and overwrite:
        raise click.UsageError("--resume continues --output, --overwrite replaces it: give one")
    if resume and init_from:
        raise click.UsageError("--resume continues --output, --init-from starts a new run: give one")
    path = options.output_path(output, overwrite or resume)
    device = options.resolve_device(device)
    simulator_config = simulator_config_for(
        architecture,
        size,
        collision_radius,
        max_faces,
        max_static_edge or None,
        max_vertex_offset or None,
        speculative,
        state,
        static_receivers,
    )
    training_config = TrainingConfig(
        steps=steps,
        batch_size=batch_size,
        learning_rate_initial=learning_rate[0],
        learning_rate_final=learning_rate[1],
        loss=loss,
        target_keeps_noise=target_keeps_noise,
        checkpoint_every=checkpoint_every,
        seed=seed,
        precision=resolve_precision(precision, device),
    )
    resume_from = path if resume and path.exists() else None
    trainer = make_trainer(
        dataset, simulator_config, training_config, device, resume_from, init_from, workers
    )
    with options.progress(
        total=steps, initial=trainer.step, unit="step", desc="train", disable=trainer.rank != 0 or None
    ) as bar:
        trainer.run(
            path,
            on_step=lambda step, loss: (bar.update(1), bar.set_postfix(loss=f"{loss:.4g}")),
            on_checkpoint=lambda: log_csv and trainer.rank == 0 and write_loss_csv(log_csv, trainer.history),
        )
    if trainer.rank != 0:
        return
    if rerun_path:
        from fignetctl.core.viz import log_scalars_to_rerun

        log_scalars_to_rerun(rerun_path, "train", {"loss": [(h["step"], h["loss"]) for h in trainer.history]})
    click.echo(str(path))
