"""The checkpoints shipped inside the package."""

import dataclasses
import json

import numpy as np

from fignetctl.core import movi
from fignetctl.core.containers import WEIGHTS_HASH_KEY
from fignetctl.core.model.apply import load_model
from fignetctl.core.model.checkpoint import BUNDLED, bundled_model_path, read_checkpoint_payload
from fignetctl.core.model.rollout import rollout
from fignetctl.core.model.scene_data import scene_from_trajectory
from tests.conftest import box_drop_file


def test_bundled_checkpoints_are_small_and_differ_only_in_surface_edges():
    configs = {}
    for name in BUNDLED:
        path = bundled_model_path(name)
        assert path.stat().st_size < 5 * 2**20
        payload = read_checkpoint_payload(path)  # checks the weights against their checksum
        assert "training_state" not in payload and payload.get(WEIGHTS_HASH_KEY)
        model = load_model(name)
        assert model.rotations == 4 and model.trained_properties  # what rollout runs them with
        configs[name] = model.config
    star, full = configs["fignet-star-movi-b"], configs["fignet-movi-b"]
    assert not star.graph.surface_edges and full.graph.surface_edges
    assert dataclasses.replace(full, graph=star.graph) == star
    movi_b = movi.movi_config("movi-b")  # what they were trained on: make-dataset --preset movi-b
    assert star.dt == movi_b.dt and star.gravity == tuple(movi_b.gravity)


def test_default_model_rolls_a_box_dropped_on_the_floor_out_finitely():
    simulator = load_model()
    data = box_drop_file(frames=3, dt=1 / 30, height=0.8)
    scene = scene_from_trajectory(data, "00000", simulator.config)
    positions, quaternions = rollout(simulator, scene, 30)
    assert np.isfinite(positions).all() and np.isfinite(quaternions).all()
    assert np.abs(positions[:, 1] - positions[1, 1]).max() < 5.0  # nothing flies off


def test_make_checkpoints_trains_the_bundled_models_settings():
    """`make checkpoints` reproduces the bundled models only if its lineage's commands are ones
    `train` takes, each stage starts from the one before, and the last stage of each model gives
    every setting in which the bundled model differs from `train`'s defaults."""
    import re
    import shlex
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    import pytest

    from fignetctl.commands import options
    from fignetctl.commands.train import train
    from fignetctl.stages import train as stage

    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    root = Path(__file__).resolve().parents[3]
    made = subprocess.run(
        ["make", "-n", "--no-print-directory", "checkpoints", "DATA=/nonexistent"],
        cwd=root,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert "scripts/velocity_lineage.py --data /nonexistent --out /nonexistent/lineage" in made
    exports = [shlex.split(line) for line in made.splitlines() if "export_model.py" in line]
    exported = {Path(words[3]).stem: Path(words[2]) for words in exports}
    assert sorted(exported) == sorted(BUNDLED) and all(
        words[-2:] == ["--rotations", "4"] for words in exports
    )
    printed = subprocess.run(
        [
            sys.executable,
            "scripts/velocity_lineage.py",
            "--dry-run",
            "--data",
            "/nonexistent",
            "--out",
            "/nonexistent/lineage",
        ],
        cwd=root,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    trained = {}  # run file -> its settings
    finished = set()  # the stages' models so far
    for line in printed.splitlines():
        words = shlex.split(line)
        if words[1].endswith("average_models.py"):
            # the runs it averages, or a run and an earlier stage's model
            sources = [word for word in words[2:-2] if word.endswith(".pt")]
            assert {Path(source.replace(".run.pt", ".pt")) for source in sources} <= finished, line
            runs = {
                Path(source.replace(".run.pt", ".pt")) for source in sources if source.endswith(".run.pt")
            }
            finished = (finished - runs) | {Path(words[-1])}
        elif "train" in words and words[words.index("train") - 1].endswith("fignetctl"):
            arguments = words[words.index("train") + 1 :]
            values = train.make_context("train", arguments).params
            assert (Path(values["init_from"]) in finished) if trained else values["init_from"] is None, line
            trained[Path(values["output"])] = options.settings_from(stage.Settings, values)
            finished.add(Path(re.sub(r"\.run\.pt$", ".pt", values["output"])))
    assert len(trained) == 18  # sixteen stages, two of them two seeds each

    def recorded_by(training, recorded):
        """Whether a run's settings are the ones a model file recorded for the run that made it
        (an older trainer recorded fewer; "auto" precision is recorded as what it resolved to)."""
        made = {k: v for k, v in dataclasses.asdict(training).items() if k in recorded and k != "precision"}
        assert {"steps", "batch_size", "seed", "rest_weight", "frame_sampling"} <= made.keys()
        return made == {key: recorded[key] for key in made}

    runs = [stage.configs(settings)[1] for settings in trained.values()]
    for name, final in exported.items():
        config, training = stage.configs(trained[final.with_name(final.stem + ".run.pt")])
        bundled = load_model(name).config
        assert dataclasses.replace(config, dt=bundled.dt, gravity=bundled.gravity) == bundled, name
        provenance = read_checkpoint_payload(bundled_model_path(name))["provenance"]
        # a mean of models records each source's provenance
        sources = provenance.get("averaged_from", [provenance])
        recorded = [json.loads(source["training_config"]) for source in sources]
        assert recorded_by(training, recorded[0]), name  # the last stage's own run
        assert all(any(recorded_by(run, other) for run in runs) for other in recorded[1:]), name


def test_make_resumes_a_model_file_newer_than_its_data():
    """A training target whose model file is newer than its data may be half-trained (make was
    interrupted): make must still run its recipe, which then resumes that file."""
    import os
    import shlex
    import shutil
    import subprocess
    import tempfile
    from pathlib import Path

    import pytest

    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    root = Path(__file__).resolve().parents[3]
    with tempfile.TemporaryDirectory() as folder:
        data = Path(folder)
        for name, age in (("movi-b-train.h5", 100), ("fignet-star-movi-b-base.pt", 0)):
            (data / name).write_bytes(b"")
            os.utime(data / name, (1e9 - age, 1e9 - age))
        made = subprocess.run(
            ["make", "-n", "--no-print-directory", str(data / "fignet-star-movi-b-base.pt"), f"DATA={data}"],
            cwd=root,
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    trains = [shlex.split(line) for line in made.splitlines() if " train " in line]
    assert len(trains) == 1 and trains[0][-1] == "--resume", made
