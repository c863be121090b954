"""tradeoff: accuracy against seconds for the knobs that trade one for the other (the sweeps
themselves are in fignetctl.bench.tradeoff)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from fignetctl.bench.tradeoff import KNOBS
from fignetctl.errors import SettingError
from fignetctl.stages import check, device_setting, no_progress, resolve_device, setting

KNOB_CHOICES = (*KNOBS, "all")
OUTPUT_EXTENSIONS = ("json", "csv", "png")


@dataclasses.dataclass(frozen=True)
class Settings:
    trajectories: int | None = setting(
        None, "Trajectories rolled out per setting.  [default: 4]", low=1, high=10**6
    )
    steps: int | None = setting(
        None, "Rollout steps; the error is taken at the last.  [default: 30]", low=1, high=10**6
    )
    repeats: int | None = setting(
        None,
        "Timed runs per setting and object (marching-cubes, bench-memory pairs).  [default: 3]",
        low=1,
        high=1000,
    )
    train_steps: int | None = setting(
        None, "Training steps of each message-passing model.  [default: 150]", low=1, high=10**8
    )
    threads: int = setting(1, "Torch CPU threads while measuring; 0 keeps torch's default.", low=0, high=1024)
    quick: bool = setting(False, "Two settings per knob, one trajectory, two steps: a smoke run in seconds.")
    seed: int = setting(0, "Random seed, 0 to 2**32 - 1.", low=0, high=2**32 - 1)
    device: str = device_setting()


def selected(knobs) -> list[str]:
    """The knobs asked for, in order, once each; 'all' means every knob."""
    from fignetctl.bench.tradeoff import KNOBS

    return list(KNOBS) if "all" in knobs else list(dict.fromkeys(knobs))


def input_problem(knobs, capture=None, nerf=None, nerf_curve=None) -> str | None:
    """What a knob needs and was not given."""
    if "marching-cubes" in knobs and not (capture and nerf):
        return "marching-cubes needs --capture (render-views output) and --nerf (fit-nerf on it)"
    if "nerf-steps" in knobs and not nerf_curve:
        return "nerf-steps needs --nerf-curve (a learning curve from benchmarks/bench_nerf.py)"
    return None


def output_files(out_dir, knob) -> list[Path]:
    """The json, csv and png a knob's sweep writes into `out_dir`."""
    return [Path(out_dir) / f"tradeoff-{knob}.{ext}" for ext in OUTPUT_EXTENSIONS]


def run(
    knobs,
    out_dir,
    settings: Settings = Settings(),
    data=None,
    train_data=None,
    capture=None,
    nerf=None,
    nerf_curve=None,
    progress=None,
    echo=None,
) -> dict:
    """Sweep each of `knobs` (see `selected`) and write its accuracy against seconds into the
    folder `out_dir` (`output_files`: json, csv, png). The sweeps read `data` (ground truth),
    `train_data`, `capture` and `nerf` (marching-cubes), `nerf_curve` (nerf-steps); movi-b
    ground truth not given is made in `out_dir` and kept there. `echo(line)`, when given, gets
    each json's path as it is written. Returns {"outputs": {knob: its json path}}."""
    from fignetctl.bench import tradeoff as core

    check(settings)
    knobs, out_dir = selected(knobs), Path(out_dir)
    if problem := input_problem(knobs, capture, nerf, nerf_curve):
        raise SettingError(problem)
    base = core.QUICK if settings.quick else core.TradeoffSettings()
    given = {name: getattr(settings, name) for name in ("trajectories", "steps", "repeats", "train_steps")}
    config = dataclasses.replace(
        base,
        **{k: v for k, v in given.items() if v is not None},
        threads=settings.threads or None,
        seed=settings.seed,
        device=resolve_device(settings.device),
    )
    inputs = {
        "data": data,
        "train_data": train_data,
        "capture": capture,
        "nerf": nerf,
        "nerf_curve": nerf_curve,
    }
    bars = progress or no_progress
    inputs.update(ground_truth_files(knobs, inputs, out_dir, config, bars))
    written = {}
    for knob in knobs:
        with bars(desc=knob, unit="run") as bar:
            result = run_knob(core, knob, inputs, config, counter(bar))
        paths = output_files(out_dir, knob)
        core.write_result(result, *paths)
        written[knob] = str(paths[0])
        if echo is not None:
            echo(written[knob])
    return {"outputs": written}


def ground_truth_files(knobs, inputs, out_dir, config, bars) -> dict:
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
                with bars(total=count, unit="traj", desc=f"make {path.name}") as bar:
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
        "rotations": core.sweep_rotations,
    }[knob]
    return sweep(inputs["data"], config, on_progress)
