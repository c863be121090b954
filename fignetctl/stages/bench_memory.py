"""bench-memory: edges, runtime and peak memory of FIGNet and FIGNet* (the paper's Table 1)."""

from __future__ import annotations

import dataclasses

from fignetctl.errors import SettingError
from fignetctl.stages import check, device_setting, no_progress, resolve_device, setting, write_summary


@dataclasses.dataclass(frozen=True)
class Settings:
    size: str | None = setting(
        None,
        "Network size preset of the untrained models.  [default: paper]",
        choices=("tiny", "small", "paper"),
    )
    max_faces: int | None = setting(
        None,
        "Decimate each mesh to at most this many faces; 0 keeps the meshes whole.  [default: 256]",
        low=0,
        high=10**6,
    )
    collision_radius: float | None = setting(
        None, "Face-face edge radius in metres.  [default: 0.2]", low=0, low_open=True
    )
    samples: int = setting(10, "(trajectory, frame) pairs per data file.", low=1, high=10**5)
    repeats: int = setting(
        5, "Timed runs per pair, model and phase, after one warm-up run.", low=1, high=1000
    )
    threads: int = setting(
        1, "Torch CPU threads while measuring; 0 keeps torch's default (all cores).", low=0, high=1024
    )
    seed: int = setting(0, "Random seed, 0 to 2**32 - 1.", low=0, high=2**32 - 1)
    device: str = device_setting()


def model_problem(settings: Settings, model_paths) -> str | None:
    """What is wrong with giving model files and the settings of untrained models together."""
    if model_paths and (settings.size or settings.max_faces is not None or settings.collision_radius):
        return "--model files carry their own settings: drop --size, --max-faces and --collision-radius"
    return None


def run(
    data, settings: Settings = Settings(), model_paths=(), json_path=None, markdown_path=None, progress=None
) -> dict:
    """Measure the models `model_paths` (default: untrained FIGNet and FIGNet* of `settings.size`)
    on (trajectory, frame) pairs of each trajectory file in `data`: edges by type, milliseconds
    and peak memory per step and per training step. Writes the full results (with provenance)
    to `json_path` and the markdown tables to `markdown_path`; returns the results with the
    tables as `markdown`."""
    from fignetctl.bench import memory as benchmark
    from fignetctl.core.atomic import atomic_path
    from fignetctl.core.provenance import stamp

    check(settings)
    if problem := model_problem(settings, model_paths):
        raise SettingError(problem)
    config = benchmark.BenchmarkSettings(
        samples=settings.samples,
        repeats=settings.repeats,
        seed=settings.seed,
        device=resolve_device(settings.device),
        threads=settings.threads or None,
    )
    if model_paths:
        simulators = benchmark.simulators_from_files(model_paths)
    else:
        max_faces = 256 if settings.max_faces is None else (settings.max_faces or None)
        simulators = benchmark.untrained_simulators(
            settings.size or "paper", settings.collision_radius, max_faces, settings.seed
        )
    with (progress or no_progress)(
        total=settings.samples * len(data), unit="pair", desc="bench-memory"
    ) as bar:
        result = benchmark.run_benchmark(data, simulators, config, on_pair=lambda: bar.update(1))
    provenance = stamp(
        **{f"data_{i}": p for i, p in enumerate(data)},
        **{f"model_{i}": p for i, p in enumerate(model_paths)},
    )
    result = {**result, **provenance}
    report = benchmark.markdown_report(result)
    write_summary(json_path, result, provenance)
    if markdown_path is not None:
        with atomic_path(markdown_path) as tmp:
            tmp.write_text(report)
    return {**result, "markdown": report}
