"""`python scripts/velocity_lineage.py [--data DIR] [--out DIR] [--dry-run]`: train the bundled
velocity-state FIGNet* and FIGNet from scratch, stage by stage, each stage from the model of the
one before (`train --init-from`), as docs/simulator.md ("The bundled models' lineage") lists
them. A finished stage's model is kept as OUT/STAGE.pt and skipped when the script runs
again; an interrupted stage goes on from its last checkpoint (`train --resume`). Two-seed
stages run their seeds side by side, one per core, and average them (scripts/average_models.py),
as a stage with `mean_with` averages its run with an earlier stage's model; data-parallel
stages run under torchrun on two processes. About 21 hours on a 2-core CPU.

The data: DIR/movi-b-train.h5 (600 trajectories), DIR/movi-b-train-4k.h5 (4000) and
DIR/movi-b-train-16k.h5 (16,000), as `make checkpoints` makes them. `--dry-run` prints the
commands instead of running them. `make checkpoints` runs this, then exports the last stages."""

import argparse
import dataclasses
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

# What every stage gives beyond `train`'s defaults (velocity state, MSE, uniform frames, bf16
# where the CPU has it, static nodes that send but do not aggregate).
COMMON = ["--state", "velocities", "--size", "small", "--max-faces", "256", "--collision-radius", "0.2"]
DATA = {
    "600": "movi-b-train.h5",
    "4k": "movi-b-train-4k.h5",
    "16k": "movi-b-train-16k.h5",
    "1000": "movi-b-train-16k-first-1000.h5",  # stage 13's: the first 1000 of the 16,000
}


@dataclasses.dataclass(frozen=True)
class Stage:
    name: str
    data: str  # a key of DATA
    steps: int
    batch_size: int  # per process
    seeds: tuple[int, ...]  # two: one run per seed, side by side, then averaged
    learning_rate: tuple[str, str] = ("1e-4", "1e-5")
    pushforward: int = 0  # per process
    processes: int = 1  # 2: data-parallel under torchrun
    workers: int = 1  # graph-building processes per trainer; None: all cores but one
    start: str | None = "previous"  # the stage whose model it starts from; None: from scratch
    model: str = "fignet-star"
    extra: tuple[str, ...] = ()
    mean_with: str | None = None  # an earlier stage whose model is averaged with this one's run


STAGES = [
    Stage("scratch", "600", 8000, 8, (0,), ("3e-4", "3e-5"), start=None),
    Stage("stage-1", "600", 8000, 8, (11,)),
    Stage("stage-2", "600", 11000, 4, (12,), pushforward=1),
    Stage("stage-3", "4k", 10000, 4, (13,), pushforward=1),
    Stage("stage-4", "4k", 20000, 4, (14,), pushforward=1),
    Stage("stage-5", "4k", 14000, 4, (15,), pushforward=1),
    Stage("stage-6", "4k", 12000, 4, (16,), pushforward=1),
    Stage("stage-7", "4k", 9000, 4, (17, 18), pushforward=1),
    Stage("stage-8", "4k", 7500, 4, (19, 20), pushforward=1),
    Stage("stage-11", "4k", 1400, 64, (23,), ("3e-4", "3e-5"), pushforward=16, processes=2),
    Stage("stage-12", "16k", 900, 64, (24,), pushforward=16, processes=2),
    Stage("stage-13", "1000", 400, 128, (25,), workers=None),
    Stage("stage-14", "4k", 700, 64, (26,), processes=2),
    Stage("rest-weight-100", "4k", 1000, 64, (31,), extra=("--rest-weight", "100")),
    Stage("unroll-4-mean", "4k", 400, 64, (34,), extra=("--rest-weight", "100", "--unroll", "4"),
          mean_with="rest-weight-100"),
    Stage("fignet-rest-weight-100", "4k", 1000, 64, (31,), start="stage-14", model="fignet",
          extra=("--rest-weight", "100")),
]  # fmt: skip
BUNDLED = {"fignet-star-movi-b": "unroll-4-mean", "fignet-movi-b": "fignet-rest-weight-100"}


def model_path(out: Path, stage_name: str) -> Path:
    return out / f"{stage_name}.pt"


def train_command(stage: Stage, data: Path, seed: int, run: Path, start: Path | None, resume: bool):
    """The `fignetctl train` command line of one run of `stage` into `run`."""
    fignetctl = str(Path(sys.executable).with_name("fignetctl"))
    launcher = [fignetctl]
    if stage.processes > 1:
        launcher = [sys.executable, "-m", "torch.distributed.run", "--standalone",
                    f"--nproc_per_node={stage.processes}", fignetctl]  # fmt: skip
    workers = stage.workers if stage.workers is not None else max(1, (os.cpu_count() or 2) - 1)
    command = [
        *launcher, "train", str(data / DATA[stage.data]), "-o", str(run), "--model", stage.model, *COMMON,
        "--batch-size", str(stage.batch_size), "--steps", str(stage.steps),
        "--learning-rate", *stage.learning_rate, "--seed", str(seed), "--workers", str(workers),
        "--pushforward", str(stage.pushforward), "--checkpoint-every", "50",
        "--log-csv", str(run.with_suffix(".csv")), *stage.extra,
    ]  # fmt: skip
    if resume:
        command.append("--resume")
    elif start is not None:
        command += ["--init-from", str(start)]
    return command


def stage_runs(stage: Stage, data: Path, out: Path):
    """(command, run file) of each run of `stage`, resuming a run whose checkpoint exists."""
    previous = STAGES[STAGES.index(stage) - 1].name if stage.start == "previous" else stage.start
    start = model_path(out, previous) if previous else None
    runs = []
    for seed in stage.seeds:
        suffix = f"-seed-{seed}" if len(stage.seeds) > 1 else ""
        run = out / f"{stage.name}{suffix}.run.pt"
        runs.append((train_command(stage, data, seed, run, start, run.exists()), run))
    return runs


def stage_mean(stage: Stage, runs, out: Path):
    """The `average_models.py` command that makes `stage`'s model from its runs (and the model
    of the stage it names in `mean_with`, whose trained properties an older trainer may have
    recorded differently: the run's are kept), or None where its one run is its model."""
    sources = [run for _, run in runs] + ([model_path(out, stage.mean_with)] if stage.mean_with else [])
    if len(sources) == 1:
        return None
    return average_command(
        sources, model_path(out, stage.name), properties_from=1 if stage.mean_with else None
    )


def run_stage(stage: Stage, data: Path, out: Path, dry_run: bool) -> None:
    final = model_path(out, stage.name)
    runs = stage_runs(stage, data, out)
    mean = stage_mean(stage, runs, out)
    one_thread = {**os.environ, "OMP_NUM_THREADS": "1"}  # the workers and the other seed take the rest
    if dry_run:
        for command, _ in runs:
            print(shlex.join(command))
        if mean:
            print(shlex.join(mean))
        return
    if final.exists():
        print(f"{final}: done")
        return
    processes = [subprocess.Popen(command, env=one_thread) for command, _ in runs]
    codes = [process.wait() for process in processes]
    if any(codes):
        sys.exit(
            f"error: stage {stage.name} stopped (exit codes {codes}); run this script again to resume it"
        )
    if mean:
        subprocess.run(mean, check=True)
    else:
        shutil.copyfile(runs[0][1], final)


def average_command(sources, destination, properties_from=None):
    script = Path(__file__).with_name("average_models.py")
    chosen = [] if properties_from is None else ["--properties-from", str(properties_from)]
    return [sys.executable, str(script), *chosen, *map(str, sources), "-o", str(destination)]


def take_first_1000(data: Path, dry_run: bool) -> None:
    destination = data / DATA["1000"]
    command = [sys.executable, str(Path(__file__).with_name("take_trajectories.py")),
               str(data / DATA["16k"]), str(destination), "-n", "1000"]  # fmt: skip
    if dry_run:
        print(shlex.join(command))
    elif not destination.exists():
        subprocess.run(command, check=True)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="python scripts/velocity_lineage.py", description=__doc__)
    parser.add_argument("--data", type=Path, default=Path("data"), help="where the training files are")
    parser.add_argument("--out", type=Path, default=Path("data/lineage"), help="where the stages' models go")
    parser.add_argument("--dry-run", action="store_true", help="print the commands, run nothing")
    args = parser.parse_args()
    if not args.dry_run:
        missing = [name for key, name in DATA.items() if key != "1000" and not (args.data / name).exists()]
        if missing:
            sys.exit(f"error: {args.data} lacks {', '.join(missing)}; `make checkpoints` makes them")
        args.out.mkdir(parents=True, exist_ok=True)
    for stage in STAGES:
        if stage.data == "1000":
            take_first_1000(args.data, args.dry_run)
        run_stage(stage, args.data, args.out, args.dry_run)
    for bundled, stage_name in BUNDLED.items():
        print(f"{bundled}: {model_path(args.out, stage_name)}")
