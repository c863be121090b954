"""Training throughput: samples (scenes) per second of `fignetctl train`'s loop, side by side.

Each setting trains the same model on the same file from the same start for --steps steps
after a warm-up, in one stream of batches (the normalizer statistics are frozen by then, as
after step 500 of a real run). The warm-up also runs 2 × PREFETCH_FACTOR steps per worker: the
workers fill a queue of that many batches per worker while the trainer starts, and timing the
trainer while it drains that queue measures how fast it consumes batches, not how fast they
are built (on a 16-core GPU machine, 1041 samples/s from a full queue against 444 over a
400-step run). The settings take turns --rounds times
so that a noisy host hurts them alike. The first setting is the serial design (graphs built in
the training process, float32, one thread, static receivers, every MLP on its concatenated
input: the bundled models' training); every other is reported as a ratio to it. The last
two run two data-parallel processes under torchrun (each its own batch of --batch-size, so
twice the samples per step, as the paper's 8 devices each took 16 of its 128).
bf16 settings run only on a CPU with native bfloat16 (`resolve_precision("auto")`): emulated,
it is several times slower than float32.

The serial design runs on today's code (its graph building is today's). With --before DIR, a
checkout of commit 7143ceb^, the serial trainer before the velocity state and the workers
(`git worktree add DIR 7143ceb^`), that trainer itself is timed too, at batch 4 (its `train`
default) and --batch-size, in a process that imports fignetctl from DIR, on a version 1 copy of
the data (its reader knows no other), and every setting is also given as a ratio to it.

    git worktree add /tmp/before 7143ceb^
    python benchmarks/bench_training.py data/movi-b-train.h5 --batch-size 16 --steps 12 --rounds 3 \
        --before /tmp/before -o benchmarks/results/training-throughput-avx512-batch16.json

With --device cuda the settings are the GPU's instead, from the network on the GPU with the
graphs built in the training process, reported as ratios to that:

    python benchmarks/bench_training.py data/movi-b-train.h5 --device cuda --batch-size 128 \
        --steps 20 --rounds 1 --init-from MODEL -o gpu-throughput.json
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import h5py
import torch

from fignetctl.core.atomic import write_json
from fignetctl.core.model.network import EncodeProcessDecode, concatenated_forward
from fignetctl.core.model.training import (
    PREFETCH_FACTOR,
    TrainingSettings,
    make_trainer,
    resolve_precision,
    simulator_config_for,
)
from fignetctl.core.trajectory import VELOCITY_FIELDS

FORWARD = EncodeProcessDecode.forward


class Setting(NamedTuple):
    concatenated: bool  # every MLP on its concatenated input (the network as the bundled models trained)
    state: str
    static_receivers: bool
    workers: int
    precision: str
    threads: int
    processes: int
    batch: int | None = None  # scenes per step and process (None: --batch-size)
    pushforward: int = 0  # examples per step from a model's prediction (needs --init-from)
    device: str = "cpu"
    fixed_pushforward: bool = False  # from the --init-from model's, built by the workers


FAST = resolve_precision("auto", "cpu")  # bf16 where native, else fp32
SERIAL = Setting(True, "positions", True, 0, "fp32", 1, 1)
SETTINGS = {
    "serial (positions, fp32, 1 thread, graphs in the loop, concatenated MLP inputs)": SERIAL,
    "serial at batch 4 (`train`'s default batch)": SERIAL._replace(batch=4),
    "velocities, no static receivers": Setting(True, "velocities", False, 0, "fp32", 1, 1),
    "+ first layers per distinct node": Setting(False, "velocities", False, 0, "fp32", 1, 1),
    "+ 1 worker process": Setting(False, "velocities", False, 1, "fp32", 1, 1),
    "+ bf16": Setting(False, "velocities", False, 1, "bf16", 1, 1),
    f"+ 2 threads ({FAST})": Setting(False, "velocities", False, 1, FAST, 2, 1),
    f"2 processes (torchrun), {FAST}, graphs in each": Setting(False, "velocities", False, 0, FAST, 1, 2),
    f"2 processes (torchrun), {FAST}, each fed by 1 worker": Setting(
        False, "velocities", False, 1, FAST, 1, 2
    ),
}
if FAST != "bf16":
    del SETTINGS["+ bf16"]


def builders() -> int:
    """Graph-building workers that leave the training process a core."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, cores - 1)


def gpu_settings() -> dict:
    """--device cuda: the network on the GPU in bf16, fed by more and more graph builders (all
    the cores but the training process's)."""
    gpu = Setting(False, "velocities", False, 0, "bf16", 1, 1, device="cuda")
    settings = {"GPU (bf16), graphs built in the training process": gpu}
    for workers in sorted({min(4, builders()), builders()}):
        settings[f"GPU, {workers} graph-building workers"] = gpu._replace(workers=workers)
    return settings


def pushforward_settings(base: Setting, batch: int) -> dict:
    """`base` with a quarter of each batch from pushforward: from the trained model's predictions,
    made and built in the training process one scene at a time, or from a fixed model's (the
    --init-from model: `train --pushforward-model`), built by the workers with the others."""
    where = "GPU" if base.device == "cuda" else FAST
    quarter = base._replace(pushforward=batch // 4)
    return {
        f"{where}, {base.workers} workers, pushforward {batch // 4} of {batch} in the training process": quarter,
        f"{where}, {base.workers} workers, pushforward {batch // 4} of {batch} from a fixed model, in the workers": (
            quarter._replace(fixed_pushforward=True)
        ),
    }


def steps_at(batch, args) -> int:
    """Timed steps at `batch`: as many samples as args.steps steps of --batch-size."""
    return max(1, args.steps * args.batch_size // batch)


def measure(path, setting, args) -> float:
    """Samples per second of one setting over args.steps steps of --batch-size after a warm-up
    (as many samples in steps of its own batch, where it has one)."""
    if setting.processes > 1:
        return measure_distributed(path, setting, args)
    return measure_here(path, setting, args)


def measure_here(path, setting, args) -> float:
    concatenated, state, static_receivers, workers, precision, threads, processes, batch = setting[:8]
    batch = batch or args.batch_size
    steps = steps_at(batch, args)
    warmup = args.warmup + 2 * workers * PREFETCH_FACTOR
    torch.set_num_threads(threads)
    # the network as the bundled models trained: each MLP on its concatenated input (same weights)
    EncodeProcessDecode.forward = concatenated_forward if concatenated else FORWARD
    simulator = simulator_config_for(
        "fignet-star", args.size, 0.2, 256, state=state, static_receivers=static_receivers
    )
    config = TrainingSettings(
        steps=warmup + steps,
        batch_size=batch,
        pushforward=setting.pushforward,
        pushforward_model=args.init_from if setting.fixed_pushforward else "",
        loss="mse",
        precision=precision,
        normalizer_accumulation_steps=args.warmup,
        checkpoint_every=10**9,
        seed=args.seed,
    )
    trainer = make_trainer(
        path, simulator, config, device=setting.device, workers=workers, init_from=args.init_from
    )
    clock = time.thread_time if args.single_core else time.perf_counter
    times = {}

    def on_step(step, loss):  # one stream of batches: the workers start before the timed steps
        times[step] = clock()

    trainer.run(on_step=on_step)
    return processes * steps * batch / (times[warmup + steps] - times[warmup])


def measure_distributed(path, setting, args) -> float:
    """The setting under torchrun; rank 0 prints its rate on the last line."""
    torchrun = Path(sys.executable).with_name("torchrun")
    command = [
        str(torchrun),
        "--standalone",
        "--nproc_per_node",
        str(setting.processes),
        __file__,
        path,
        "--as-rank",
        json.dumps(setting),
        *(
            f"--{k.replace('_', '-')}={v}"
            for k, v in vars(args).items()
            if k in ("steps", "warmup", "batch_size", "size", "seed")
        ),
    ]
    result = subprocess.run(
        command,
        capture_output=True,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": str(setting.threads)},
        check=True,
    )
    return float(result.stdout.strip().splitlines()[-1])


BEFORE = "the serial trainer of 7143ceb^ (graphs built in train_step, positions, fp32)"
BEFORE_DEFAULT_BATCH = 4  # that trainer's `train --batch-size` default
# Runs in a process that imports fignetctl from the checkout: that version's own API.
BEFORE_SCRIPT = """
import sys, time, torch, fignetctl
from fignetctl.core.model.training import TrainingConfig, make_trainer, simulator_config_for
checkout, data, size = sys.argv[1:4]
batch, steps, warmup, seed = map(int, sys.argv[4:8])
clock = time.thread_time if sys.argv[8] == "thread" else time.perf_counter  # as --single-core times
assert fignetctl.__file__.startswith(checkout), f"imported {fignetctl.__file__}, not the checkout's"
torch.set_num_threads(1)
config = TrainingConfig(steps=warmup + steps, batch_size=batch, normalizer_accumulation_steps=warmup,
                        checkpoint_every=10**9, seed=seed)
trainer = make_trainer(data, simulator_config_for("fignet-star", size, 0.2, 256), config)
times = {}
trainer.run(on_step=lambda step, loss: times.__setitem__(step, clock()))
print(steps * batch / (times[warmup + steps] - times[warmup]))
"""


def version_1_copy(path, folder) -> Path:
    """A copy of a trajectory file without velocities, marked format version 1."""
    copy = Path(folder) / "version-1.h5"
    shutil.copyfile(path, copy)
    with h5py.File(copy, "r+") as f:
        velocities = []
        f.visititems(
            lambda name, _: velocities.append(name) if name.rsplit("/", 1)[-1] in VELOCITY_FIELDS else None
        )
        for name in velocities:
            del f[name]
        f.attrs["format_version"] = 1
    return copy


def measure_before(checkout, path, batch, args) -> float:
    """Samples per second of the checkout's trainer at `batch` (as many samples as the others)."""
    checkout = str(Path(checkout).resolve())
    steps = steps_at(batch, args)
    command = [sys.executable, "-c", BEFORE_SCRIPT, checkout, str(path), args.size]
    command += [str(v) for v in (batch, steps, args.warmup, args.seed)]
    command.append("thread" if args.single_core else "wall")
    env = {**os.environ, "PYTHONPATH": checkout, "OMP_NUM_THREADS": "1"}
    result = subprocess.run(command, capture_output=True, text=True, env=env, cwd=checkout, check=False)
    if result.returncode != 0:
        sys.exit(f"the trainer in {checkout} failed: {result.stderr.strip().splitlines()[-1:]}")
    return float(result.stdout.strip().splitlines()[-1])


def cpu_name() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines() if Path("/proc/cpuinfo").exists() else []:
        if line.startswith("model name"):
            return f"{line.split(':', 1)[1].strip()}; bf16 {'native' if FAST == 'bf16' else 'emulated'}"
    return "unknown"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--size", default="small")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("-o", "--output", default=None)
    parser.add_argument(
        "--single-core",
        action="store_true",
        help="only the one-process, one-thread settings without workers, timed by the CPU time of "
        "the training thread, which other work on a busy host disturbs less than the wall clock",
    )
    parser.add_argument(
        "--before",
        metavar="DIR",
        default=None,
        help="a checkout of 7143ceb^ (git worktree add DIR 7143ceb^): time its trainer too",
    )
    parser.add_argument(
        "--device",
        choices=("cpu", "cuda"),
        default="cpu",
        help="cuda: time the GPU settings (graph builders feeding the network on the GPU) instead",
    )
    parser.add_argument(
        "--init-from",
        metavar="MODEL",
        default=None,
        help="start every setting from this model file's weights, and time pushforward too: a quarter "
        "of each batch from the trained model's predictions or from this fixed model's",
    )
    parser.add_argument(
        "--only",
        action="append",
        metavar="TEXT",
        help="only the settings whose name contains TEXT (repeatable; the first one left is the baseline)",
    )
    parser.add_argument(
        "--as-rank", default=None, help=argparse.SUPPRESS
    )  # one process of a torchrun setting
    args = parser.parse_args()
    if args.before is not None and not (Path(args.before) / "fignetctl" / "core").is_dir():
        parser.error(f"--before {args.before}: not a fignetctl checkout (git worktree add DIR 7143ceb^)")
    if args.as_rank is not None:
        rate = measure_here(args.data, Setting(*json.loads(args.as_rank)), args)
        if os.environ.get("RANK", "0") == "0":
            print(rate)
        return
    settings = dict(gpu_settings() if args.device == "cuda" else SETTINGS)
    if args.init_from is not None:
        cuda = args.device == "cuda"
        fed = Setting(
            False,
            "velocities",
            False,
            builders() if cuda else 1,
            "bf16" if cuda else FAST,
            1,
            1,
            device=args.device,
        )
        settings.update(pushforward_settings(fed, args.batch_size))
    settings = {
        name: setting
        for name, setting in settings.items()
        if not args.single_core or (setting.workers, setting.threads, setting.processes) == (0, 1, 1)
        if not args.only or any(text in name for text in args.only)
    }
    if not settings:
        parser.error(f"no setting's name contains any of {args.only}")
    timers = {name: lambda s=setting: measure(args.data, s, args) for name, setting in settings.items()}
    before_rows = []
    with tempfile.TemporaryDirectory() as folder:
        if args.before is not None:
            old_data = version_1_copy(args.data, folder)
            for batch in dict.fromkeys((BEFORE_DEFAULT_BATCH, args.batch_size)):
                before_rows.append(f"{BEFORE}, batch {batch}")
                timers[before_rows[-1]] = lambda b=batch: measure_before(args.before, old_data, b, args)
        rates = {name: [] for name in timers}
        for _ in range(args.rounds):
            for name, timer in timers.items():
                rates[name].append(timer())
                print(f"{name}: {rates[name][-1]:.2f} samples/s", flush=True)
    medians = {name: statistics.median(r) for name, r in rates.items()}
    baseline = medians[next(iter(settings))]
    rows = {
        name: {"samples_per_s": medians[name], "all": r, "ratio": medians[name] / baseline}
        for name, r in rates.items()
    }
    if before_rows:
        for row in rows.values():
            row["ratio_to_before"] = row["samples_per_s"] / medians[before_rows[0]]
    unit = "samples per CPU-second" if args.single_core else "samples/s"
    before_column = f" × {BEFORE_DEFAULT_BATCH}-batch trainer of 7143ceb^ |" if before_rows else ""
    print(
        f"\n| setting | {unit} | × first row |{before_column}\n|---|---|---|{'---|' if before_rows else ''}"
    )
    for name, row in rows.items():
        before_cell = f" {row['ratio_to_before']:.2f} |" if before_rows else ""
        print(f"| {name} | {row['samples_per_s']:.1f} | {row['ratio']:.2f} |{before_cell}")
    if args.output:
        result = {
            "data": args.data,
            "cpus": os.cpu_count(),
            "cpu": cpu_name(),
            "gpu": torch.cuda.get_device_name() if args.device == "cuda" else None,
            "clock": "training thread's CPU time" if args.single_core else "wall",
            "settings": {k: v._asdict() for k, v in settings.items()},
            "args": vars(args),
            "results": rows,
        }
        write_json(args.output, result)


if __name__ == "__main__":
    main()
