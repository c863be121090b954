"""`fignetctl tradeoff`: accuracy against seconds for the knobs that trade one for the other."""

import click

from fignetctl.commands import options

KNOB_CHOICES = [
    "decimation",
    "architecture",
    "collision-radius",
    "message-passing",
    "marching-cubes",
    "nerf-steps",
    "device",
    "all",
]


@click.command("tradeoff")
@click.argument("knobs", nargs=-1, required=True, type=click.Choice(KNOB_CHOICES))
@click.option(
    "-o",
    "--out-dir",
    type=click.Path(file_okay=False),
    required=True,
    help="Folder for tradeoff-KNOB.json, .csv and .png.",
)
@click.option(
    "--data",
    type=click.Path(exists=True, dir_okay=False),
    default=None,
    help="Ground-truth trajectory file for the simulator knobs.  [default: 8 movi-b trajectories made in OUT_DIR]",
)
@click.option(
    "--train-data",
    type=click.Path(exists=True, dir_okay=False),
    default=None,
    help="Training file of the message-passing sweep.  [default: 16 movi-b trajectories made in OUT_DIR]",
)
@click.option(
    "--capture",
    type=click.Path(exists=True, file_okay=False),
    default=None,
    help="render-views folder (prompts.json, ground_truth/) for marching-cubes.",
)
@click.option(
    "--nerf",
    type=click.Path(exists=True, dir_okay=False),
    default=None,
    help="nerf.pt of that capture for marching-cubes (fignetctl fit-nerf --preset fast).",
)
@click.option(
    "--nerf-curve",
    type=click.Path(exists=True, dir_okay=False),
    default=None,
    help="Learning-curve json of benchmarks/bench_nerf.py for nerf-steps (the repository has one: "
    "benchmarks/results/nerf_psnr_vs_time.json).",
)
@click.option(
    "--trajectories",
    type=click.IntRange(min=1, max=10**6),
    default=None,
    help="Trajectories rolled out per setting.  [default: 4]",
)
@click.option(
    "--steps",
    type=click.IntRange(min=1, max=10**6),
    default=None,
    help="Rollout steps; the error is taken at the last.  [default: 30]",
)
@click.option(
    "--repeats",
    type=click.IntRange(min=1, max=1000),
    default=None,
    help="Timed runs per setting and object (marching-cubes, bench-memory pairs).  [default: 3]",
)
@click.option(
    "--train-steps",
    type=click.IntRange(min=1, max=10**8),
    default=None,
    help="Training steps of each message-passing model.  [default: 150]",
)
@click.option(
    "--threads",
    type=click.IntRange(min=0, max=1024),
    default=1,
    show_default=True,
    help="Torch CPU threads while measuring; 0 keeps torch's default.",
)
@click.option(
    "--quick", is_flag=True, help="Two settings per knob, one trajectory, two steps: a smoke run in seconds."
)
@options.seed_option
@options.device_option
@options.overwrite_option
def tradeoff(
    knobs,
    out_dir,
    data,
    train_data,
    capture,
    nerf,
    nerf_curve,
    trajectories,
    steps,
    repeats,
    train_steps,
    threads,
    quick,
    seed,
    device,
    overwrite,
):
    """Sweep KNOBS and write, per knob, accuracy against seconds as json, csv and a PNG with
    the Pareto front marked; every point is a median with its quartiles (docs/accuracy-vs-time.md).

    \b
    Knobs: decimation, architecture, collision-radius, message-passing (trains small
    models), marching-cubes (needs --capture and --nerf), nerf-steps, device; or all.

    \b
    Example:
      fignetctl make-dataset --preset movi-b --split test -n 8 --seed 11 -o gt.h5
      fignetctl tradeoff decimation collision-radius --data gt.h5 -o tradeoff/
      fignetctl tradeoff marching-cubes --capture capture --nerf nerf.pt -o tradeoff/
      fignetctl tradeoff nerf-steps --nerf-curve benchmarks/results/nerf_psnr_vs_time.json -o /tmp/t
    """
    import dataclasses
    from pathlib import Path

    from fignetctl.bench import tradeoff as core

    knobs = list(core.KNOBS) if "all" in knobs else list(dict.fromkeys(knobs))
    if "marching-cubes" in knobs and not (capture and nerf):
        raise click.UsageError(
            "marching-cubes needs --capture (render-views output) and --nerf (fit-nerf on it)"
        )
    if "nerf-steps" in knobs and not nerf_curve:
        raise click.UsageError(
            "nerf-steps needs --nerf-curve (a learning curve from benchmarks/bench_nerf.py)"
        )
    out_dir = Path(out_dir)
    outputs = {
        knob: [
            options.output_path(out_dir / f"tradeoff-{knob}.{ext}", overwrite, "--out-dir")
            for ext in ("json", "csv", "png")
        ]
        for knob in knobs
    }
    base = core.QUICK if quick else core.TradeoffConfig()
    given = {"trajectories": trajectories, "steps": steps, "repeats": repeats, "train_steps": train_steps}
    config = dataclasses.replace(
        base,
        **{k: v for k, v in given.items() if v is not None},
        threads=threads or None,
        seed=seed,
        device=options.resolve_device(device),
    )
    inputs = {
        "data": data,
        "train_data": train_data,
        "capture": capture,
        "nerf": nerf,
        "nerf_curve": nerf_curve,
    }
    inputs.update(ground_truth_files(knobs, inputs, out_dir, config))
    for knob in knobs:
        with options.progress(desc=knob, unit="run") as bar:
            result = run_knob(core, knob, inputs, config, counter(bar))
        core.write_result(result, *outputs[knob])
        click.echo(str(outputs[knob][0]))


def ground_truth_files(knobs, inputs, out_dir, config) -> dict:
    """Make the movi-b files a sweep needs and was not given (kept in OUT_DIR for reuse)."""
    from fignetctl.bench import tradeoff as core

    made = {}
    wanted = {
        "data": ("test", 2 if config.quick else 8, 11),
        "train_data": ("train", 2 if config.quick else 16, 12),
    }
    needs = {"data": set(core.KNOBS) - {"marching-cubes", "nerf-steps"}, "train_data": {"message-passing"}}
    for key, (split, count, seed) in wanted.items():
        if inputs[key] is None and needs[key] & set(knobs):
            path = out_dir / f"ground-truth-movi-b-{split}.h5"
            if not path.is_file():
                with options.progress(total=count, unit="traj", desc=f"make {path.name}") as bar:
                    core.make_ground_truth(
                        path, count, 1.0 if config.quick else 2.5, seed, split, lambda: bar.update(1)
                    )
            made[key] = str(path)
    return made


def counter(bar):
    def on_progress():
        bar.update(1)

    return on_progress


def run_knob(core, knob, inputs, config, on_progress):
    if knob == "marching-cubes":
        return core.sweep_marching_cubes(inputs["capture"], inputs["nerf"], config, on_progress)
    if knob == "nerf-steps":
        return core.sweep_nerf_steps(inputs["nerf_curve"], config)
    if knob == "message-passing":
        return core.sweep_message_passing(inputs["train_data"], inputs["data"], config, on_progress)
    sweep = {
        "decimation": core.sweep_decimation,
        "architecture": core.sweep_architecture,
        "collision-radius": core.sweep_collision_radius,
        "device": core.sweep_device,
    }[knob]
    return sweep(inputs["data"], config, on_progress)
