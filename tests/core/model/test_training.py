import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from fignetctl.core.model.checkpoint import load_checkpoint, save_checkpoint
from fignetctl.core.model.network import PRESETS
from fignetctl.core.model.rollout import RolloutError, rollout
from fignetctl.core.model.scene_graph import GraphConfig
from fignetctl.core.model.simulator import LearnedSimulator, SimulatorConfig
from fignetctl.core.model.training import (
    HeapTrimmer,
    TrainingSettings,
    _malloc_trim,
    joined,
    make_trainer,
    network_threads,
    pushforward_examples,
    resident_bytes,
    return_freed_memory,
    simulator_config_for,
    torch_threads,
)
from fignetctl.core.trajectory import read_trajectories, write_trajectories
from fignetctl.errors import FignetError, FormatError, SettingError
from tests.conftest import box_drop_file

ROOT = Path(__file__).resolve().parents[3]

TINY = SimulatorConfig(network=PRESETS["tiny"], graph=GraphConfig(0.1, False))


@pytest.fixture
def box_file(tmp_path):
    return write_trajectories(tmp_path / "box.h5", box_drop_file(frames=12))


def _config(**changes):
    return dataclasses.replace(TrainingSettings(steps=8, batch_size=2, checkpoint_every=4), **changes)


def test_tiny_model_overfits_one_trajectory(box_file):
    trainer = make_trainer(
        box_file,
        TINY,
        _config(
            steps=300, noise_translation_std=0.0, noise_rotation_std=0.0, normalizer_accumulation_steps=20
        ),
    )
    trainer.run()
    losses = [h["loss"] for h in trainer.history]
    assert np.mean(losses[-20:]) < np.mean(losses[:20]) / 10


@pytest.mark.parametrize("frame_sampling", ["uniform", "motion"])
def test_resume_gives_the_same_weights_as_an_uninterrupted_run(box_file, tmp_path, frame_sampling):
    config = _config(frame_sampling=frame_sampling)
    straight = make_trainer(box_file, TINY, config)
    straight.run()
    interrupted = make_trainer(box_file, TINY, config)
    interrupted.run(tmp_path / "half.pt", until_step=4)
    resumed = make_trainer(box_file, TINY, _config(), resume_from=tmp_path / "half.pt")  # its own settings
    assert resumed.step == 4
    resumed.run()
    for name, value in straight.simulator.state_dict().items():
        torch.testing.assert_close(resumed.simulator.state_dict()[name], value, rtol=0, atol=0)


def test_a_time_limit_stops_at_a_checkpoint_and_resumed_chunks_reach_the_same_weights(box_file, tmp_path):
    straight = make_trainer(box_file, TINY, _config())
    assert straight.run(time_limit=3600) is False and straight.step == 8
    path, chunks = tmp_path / "chunks.pt", 0
    trainer = make_trainer(box_file, TINY, _config())
    while trainer.run(path, time_limit=0):  # every chunk ends after its first step
        chunks += 1
        assert load_checkpoint(path, with_training_state=True)[1]["step"] == trainer.step == chunks
        trainer = make_trainer(box_file, TINY, _config(), resume_from=path)
    assert chunks == 7 and trainer.step == 8  # the last chunk reached the end: not stopped early
    for name, value in straight.simulator.state_dict().items():
        torch.testing.assert_close(trainer.simulator.state_dict()[name], value, rtol=0, atol=0)


def test_a_non_finite_loss_stops_training_and_keeps_the_last_checkpoint(box_file, tmp_path, monkeypatch):
    from fignetctl.core.model import training

    honest, calls = training.regression_loss, []

    def poisoned(*args):
        calls.append(1)
        loss = honest(*args)
        return loss * float("nan") if len(calls) == 6 else loss

    monkeypatch.setattr(training, "regression_loss", poisoned)
    trainer = make_trainer(box_file, TINY, _config())
    with pytest.raises(
        FignetError, match="not finite at step 6; the weights of the last checkpoint are kept"
    ):
        trainer.run(tmp_path / "run.pt")
    kept, state = load_checkpoint(tmp_path / "run.pt", with_training_state=True)
    assert state["step"] == 4 and all(torch.isfinite(v).all() for v in kept.state_dict().values())


def test_checkpoint_round_trip_keeps_predictions(box_file, tmp_path):
    trainer = make_trainer(box_file, TINY, _config())
    trainer.run()
    save_checkpoint(tmp_path / "m.pt", trainer.simulator)
    loaded = load_checkpoint(tmp_path / "m.pt")
    assert loaded.config == dataclasses.replace(
        TINY, dt=pytest.approx(1 / 60), gravity=(0.0, 0.0, -10.0)
    )  # the data's, recorded
    scene = trainer.scenes[0]
    first = rollout(trainer.simulator.eval(), scene, 3)
    second = rollout(loaded, scene, 3)
    np.testing.assert_allclose(first[0], second[0])


def test_bad_checkpoints_are_refused(tmp_path, box_file):
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"\x00not a model" * 100)
    with pytest.raises(FormatError, match="not a readable fignetctl model"):
        load_checkpoint(garbage)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(FormatError, match="not a fignetctl model file"):
        load_checkpoint(foreign)
    newer = tmp_path / "newer.pt"
    save_checkpoint(newer, LearnedSimulator(TINY), extra={"format_version": 99})
    with pytest.raises(FormatError, match="format_version 99 is not supported"):
        load_checkpoint(newer)
    with pytest.raises(FormatError, match="no such model file"):
        load_checkpoint(tmp_path / "missing.pt")


def test_resume_on_other_data_is_refused(box_file, tmp_path):
    trainer = make_trainer(box_file, TINY, _config(steps=2))
    trainer.run(tmp_path / "m.pt")
    other = write_trajectories(tmp_path / "other.h5", box_drop_file(frames=9))
    with pytest.raises(Exception, match="trained on other data"):
        make_trainer(other, TINY, _config(), resume_from=tmp_path / "m.pt")


def test_runaway_rollout_stops_with_step_and_object_and_keeps_frames(box_file):
    trainer = make_trainer(box_file, TINY, _config(steps=2))
    trainer.run()
    simulator = trainer.simulator.eval()
    with torch.no_grad():
        simulator.acceleration_normalizer.sum.mul_(1e12)  # an absurd acceleration scale
    with pytest.raises(RolloutError, match="step 0: object 1") as error:
        rollout(simulator, trainer.scenes[0], 5)
    assert error.value.positions.shape[0] == 2


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_training_on_the_gpu_follows_the_cpu_and_its_checkpoint_loads_on_the_cpu(box_file, tmp_path):
    """The same run in float32 on both devices, one example per batch from the model's own
    prediction (which runs on the model's device): the same losses, and a checkpoint written
    on the GPU loads on the CPU, where it predicts as the GPU's weights do."""
    config = _config(steps=4, batch_size=3, pushforward=1, normalizer_accumulation_steps=2)
    runs = {}
    for device in ("cpu", "cuda"):
        runs[device] = make_trainer(box_file, TINY, config, device=device)
        runs[device].run(tmp_path / f"{device}.pt")
    losses = {device: [h["loss"] for h in trainer.history] for device, trainer in runs.items()}
    np.testing.assert_allclose(losses["cuda"], losses["cpu"], rtol=1e-3)
    loaded = load_checkpoint(tmp_path / "cuda.pt")
    assert next(loaded.parameters()).device.type == "cpu"
    scene = runs["cpu"].scenes[0]
    window = (scene.geometry, scene.positions[:3], scene.quaternions[:3])
    velocities = (scene.velocities[1], scene.angular_velocities[1])
    on_gpu = runs["cuda"].simulator.eval().predict(*window, velocities=velocities)
    on_cpu = loaded.eval().predict(*window, velocities=velocities)
    assert sum(part is not None for part in on_cpu) >= 2  # positions and quaternions at least
    for gpu_part, cpu_part in zip(on_gpu, on_cpu, strict=True):
        assert (gpu_part is None) == (cpu_part is None)
        if cpu_part is not None:
            np.testing.assert_allclose(cpu_part, gpu_part, rtol=1e-4, atol=1e-6)


def _same_batch(actual, expected):
    for key in ("rows", "targets"):
        torch.testing.assert_close(actual[key], expected[key], rtol=0, atol=0)
    torch.testing.assert_close(actual["graph"].node_features, expected["graph"].node_features, rtol=0, atol=0)


def test_pushforward_from_a_fixed_model_equal_to_the_trained_one_is_the_trainers_own(box_file, tmp_path):
    """The batch that holds the pushforward examples of a fixed model with the trained model's
    weights is the one the training process makes from its own predictions; a fixed model with
    other weights starts them elsewhere."""
    config = _config(batch_size=3, pushforward=2, normalizer_accumulation_steps=2)
    trainer = make_trainer(box_file, TINY, config)
    trainer.run(until_step=2)  # the normalizers' statistics, which a prediction needs
    save_checkpoint(tmp_path / "same.pt", trainer.simulator)
    fixed = make_trainer(
        box_file, TINY, dataclasses.replace(config, pushforward_model=str(tmp_path / "same.pt"))
    )
    with torch_threads(1):  # the fixed model predicts on one thread, in any process
        own = pushforward_examples(trainer.simulator, trainer.scenes, trainer.simulator.config, config, 0, 5)
    _same_batch(fixed.batches[5], joined(trainer.batches[5], own))
    with torch.no_grad():
        for parameter in trainer.simulator.parameters():
            parameter.mul_(1.5)
    save_checkpoint(tmp_path / "other.pt", trainer.simulator)
    other = make_trainer(
        box_file, TINY, dataclasses.replace(config, pushforward_model=str(tmp_path / "other.pt"))
    )
    rows = len(trainer.batches[5]["targets"])  # the ordinary examples come first
    others, same = other.batches[5]["targets"], fixed.batches[5]["targets"]
    assert torch.equal(others[:rows], same[:rows]) and not torch.equal(others[rows:], same[rows:])


def test_a_fixed_pushforward_model_trains_alike_in_workers_and_resumes_exactly(box_file, tmp_path):
    trained_a_little = make_trainer(box_file, TINY, _config(steps=2, normalizer_accumulation_steps=2))
    trained_a_little.run()
    save_checkpoint(tmp_path / "fixed.pt", trained_a_little.simulator)
    config = _config(
        batch_size=3,
        pushforward=1,
        normalizer_accumulation_steps=2,
        pushforward_model=str(tmp_path / "fixed.pt"),
    )
    here = make_trainer(box_file, TINY, config)
    here.run()
    in_worker = make_trainer(box_file, TINY, config, workers=1)
    in_worker.run(tmp_path / "half.pt", until_step=4)
    resumed = make_trainer(box_file, TINY, _config(), resume_from=tmp_path / "half.pt", workers=1)
    assert resumed.config.pushforward_model == str(tmp_path / "fixed.pt")
    resumed.run()
    for name, value in here.simulator.state_dict().items():
        torch.testing.assert_close(resumed.simulator.state_dict()[name], value, rtol=0, atol=0)


def test_a_fixed_pushforward_model_of_another_state_or_without_pushforward_is_refused(box_file, tmp_path):
    velocity_model = LearnedSimulator(simulator_config_for("fignet-star", "tiny", 0.1, state="velocities"))
    save_checkpoint(tmp_path / "velocities.pt", velocity_model)
    with pytest.raises(FignetError, match="its state is 'velocities', the trained model's 'positions'"):
        make_trainer(
            box_file, TINY, _config(pushforward=1, pushforward_model=str(tmp_path / "velocities.pt"))
        )
    with pytest.raises(FignetError, match="with pushforward = 0"):
        make_trainer(box_file, TINY, _config(pushforward_model=str(tmp_path / "velocities.pt")))


def test_export_drops_training_state_and_keeps_provenance(box_file, tmp_path):
    from fignetctl.core.model.checkpoint import export_checkpoint

    trainer = make_trainer(box_file, TINY, _config(steps=3))
    trainer.run(tmp_path / "full.pt")
    export_checkpoint(tmp_path / "full.pt", tmp_path / "shipped.pt")
    payload = torch.load(tmp_path / "shipped.pt", weights_only=True)
    assert "training_state" not in payload and payload["provenance"]["step"] == 3
    assert (tmp_path / "shipped.pt").stat().st_size < (tmp_path / "full.pt").stat().st_size
    simulator, state = load_checkpoint(tmp_path / "shipped.pt", with_training_state=True)
    assert state is None and simulator.config == trainer.simulator.config


def test_export_records_the_time_step_and_gravity_of_a_run_saved_without_them(box_file, tmp_path):
    from fignetctl.core.model.checkpoint import export_checkpoint

    trainer = make_trainer(box_file, TINY, _config(steps=1))
    data = read_trajectories(box_file)
    assert trainer.simulator.config.dt == data.dt and trainer.simulator.config.gravity == tuple(data.gravity)
    bare = dataclasses.replace(trainer.simulator.config, dt=None, gravity=None)
    save_checkpoint(tmp_path / "old.pt", LearnedSimulator(bare))  # as runs saved before they were kept
    with pytest.raises(SettingError, match="give both"):
        export_checkpoint(tmp_path / "old.pt", tmp_path / "half.pt", dt=1 / 30)
    export_checkpoint(tmp_path / "old.pt", tmp_path / "shipped.pt", dt=1 / 30, gravity=(0, 0, -10))
    shipped = load_checkpoint(tmp_path / "shipped.pt").config
    assert shipped == dataclasses.replace(bare, dt=1 / 30, gravity=(0.0, 0.0, -10.0))
    with pytest.raises(FormatError, match="records its dt .* already"):
        export_checkpoint(tmp_path / "shipped.pt", tmp_path / "again.pt", dt=1 / 60, gravity=(0, 0, -10))
    assert not (tmp_path / "half.pt").exists() and not (tmp_path / "again.pt").exists()


def test_a_model_file_records_the_turns_rollout_and_evaluate_average_it_over(box_file, tmp_path):
    from click.testing import CliRunner

    from fignetctl.cli import cli
    from fignetctl.core.containers import save_torch_payload
    from fignetctl.core.model.checkpoint import export_checkpoint, read_checkpoint_payload

    make_trainer(box_file, TINY, _config(steps=1)).run(tmp_path / "run.pt")
    assert load_checkpoint(tmp_path / "run.pt").rotations == 1  # as trained
    export_checkpoint(tmp_path / "run.pt", tmp_path / "four.pt", rotations=4)
    assert load_checkpoint(tmp_path / "four.pt").rotations == 4
    for given, used in ((None, 4), ("1", 1), ("2", 2)):
        flags = [] if given is None else ["--rotations", given]
        result = CliRunner().invoke(
            cli,
            ["rollout", str(box_file), "--model", str(tmp_path / "four.pt"), "--steps", "1", *flags]
            + ["--sim-scale", "1", "-o", str(tmp_path / f"r{given}.h5")],
        )
        assert result.exit_code == 0, result.output
        assert read_trajectories(tmp_path / f"r{given}.h5").attrs["rotations"] == used
    with pytest.raises(SettingError, match="whole number from 1 to 64"):
        export_checkpoint(tmp_path / "run.pt", tmp_path / "bad.pt", rotations=0)
    payload = read_checkpoint_payload(tmp_path / "four.pt")
    save_torch_payload(tmp_path / "damaged.pt", {**payload, "rotations": 2.5})
    with pytest.raises(FormatError, match="'rotations' is 2.5, not a whole number of turns from 1 to 64"):
        load_checkpoint(tmp_path / "damaged.pt")


def test_averaged_runs_hold_the_mean_weights_pooled_statistics_and_each_run(box_file, tmp_path):
    from fignetctl.core.model.checkpoint import average_checkpoints, read_checkpoint_payload

    runs = []
    for seed, steps in ((1, 3), (2, 5)):
        make_trainer(box_file, TINY, _config(steps=steps, seed=seed)).run(tmp_path / f"{seed}.pt")
        runs.append(load_checkpoint(tmp_path / f"{seed}.pt").state_dict())
    average_checkpoints([tmp_path / "1.pt", tmp_path / "2.pt"], tmp_path / "soup.pt")
    soup = load_checkpoint(tmp_path / "soup.pt")
    for name, value in soup.state_dict().items():
        if value.is_floating_point():
            torch.testing.assert_close(value, (runs[0][name] + runs[1][name]) / 2, rtol=1e-6, atol=1e-7)
    pooled = (runs[0]["acceleration_normalizer.sum"] + runs[1]["acceleration_normalizer.sum"]) / (
        runs[0]["acceleration_normalizer.count"] + runs[1]["acceleration_normalizer.count"]
    )
    torch.testing.assert_close(soup.acceleration_normalizer.sum / soup.acceleration_normalizer.count, pooled)
    payload = read_checkpoint_payload(tmp_path / "soup.pt")
    assert [run["step"] for run in payload["provenance"]["averaged_from"]] == [3, 5]
    assert "training_state" not in payload and len(payload["inputs_sha256"]) > 2


def test_a_model_averaged_with_itself_predicts_as_it_does(box_file, tmp_path):
    from fignetctl.core.model.checkpoint import average_checkpoints

    make_trainer(box_file, TINY, _config(steps=3)).run(tmp_path / "run.pt")
    average_checkpoints([tmp_path / "run.pt"] * 3, tmp_path / "soup.pt")
    scene = make_trainer(box_file, TINY, _config(steps=1)).scenes[0]
    steps = [
        load_checkpoint(path).step(scene.geometry, scene.positions[:3], scene.quaternions[:3])
        for path in (tmp_path / "run.pt", tmp_path / "soup.pt")
    ]
    np.testing.assert_allclose(steps[1][0], steps[0][0], rtol=0, atol=1e-6)


def test_averaging_reads_a_setting_an_older_file_lacks_as_its_default(box_file, tmp_path):
    import json

    from fignetctl.core.containers import save_torch_payload
    from fignetctl.core.model.checkpoint import average_checkpoints, read_checkpoint_payload

    make_trainer(box_file, TINY, _config(steps=2)).run(tmp_path / "new.pt")
    payload = read_checkpoint_payload(tmp_path / "new.pt")
    settings = json.loads(payload["simulator_config"])
    assert settings["graph"].pop("inertia") is False
    save_torch_payload(tmp_path / "old.pt", {**payload, "simulator_config": json.dumps(settings)})
    average_checkpoints([tmp_path / "old.pt", tmp_path / "new.pt"], tmp_path / "soup.pt")
    assert load_checkpoint(tmp_path / "soup.pt").config == load_checkpoint(tmp_path / "new.pt").config
    assert (
        json.loads(read_checkpoint_payload(tmp_path / "soup.pt")["simulator_config"])["graph"]["inertia"]
        is False
    )


def test_averaging_refuses_one_file_and_models_of_other_settings(box_file, tmp_path):
    from fignetctl.core.model.checkpoint import average_checkpoints
    from fignetctl.errors import SettingError

    make_trainer(box_file, TINY, _config(steps=2)).run(tmp_path / "a.pt")
    other = dataclasses.replace(TINY, graph=GraphConfig(0.2, False))
    make_trainer(box_file, other, _config(steps=2)).run(tmp_path / "b.pt")
    with pytest.raises(SettingError, match="two or more"):
        average_checkpoints([tmp_path / "a.pt"], tmp_path / "soup.pt")
    with pytest.raises(FormatError, match="simulator_config differ"):
        average_checkpoints([tmp_path / "a.pt", tmp_path / "b.pt"], tmp_path / "soup.pt")
    assert not (tmp_path / "soup.pt").exists()


def test_averaging_takes_the_chosen_files_properties_only_when_told(box_file, tmp_path):
    import json

    from fignetctl.core.containers import save_torch_payload
    from fignetctl.core.model.checkpoint import average_checkpoints, read_checkpoint_payload
    from fignetctl.errors import SettingError

    make_trainer(box_file, TINY, _config(steps=2)).run(tmp_path / "a.pt")
    payload = read_checkpoint_payload(tmp_path / "a.pt")
    properties = json.loads(payload["trained_properties"])
    properties["dynamic"]["largest_side"] = [side * 1.01 for side in properties["dynamic"]["largest_side"]]
    save_torch_payload(tmp_path / "b.pt", {**payload, "trained_properties": json.dumps(properties)})
    pair = [tmp_path / "a.pt", tmp_path / "b.pt"]
    with pytest.raises(FormatError, match="trained_properties differ"):
        average_checkpoints(pair, tmp_path / "soup.pt")
    with pytest.raises(SettingError, match="properties_from must be 0 to 1, not 2"):
        average_checkpoints(pair, tmp_path / "soup.pt", properties_from=2)
    assert not (tmp_path / "soup.pt").exists()
    for chosen in (0, 1):
        average_checkpoints(pair, tmp_path / f"soup-{chosen}.pt", properties_from=chosen)
        recorded = read_checkpoint_payload(tmp_path / f"soup-{chosen}.pt")["trained_properties"]
        assert recorded == read_checkpoint_payload(pair[chosen])["trained_properties"]

    def script(*args):
        command = [sys.executable, str(ROOT / "scripts" / "average_models.py"), *map(str, pair), *args]
        return subprocess.run(command, capture_output=True, text=True, timeout=120)

    refused = script("-o", tmp_path / "soup.pt")
    assert refused.returncode != 0 and "Traceback" not in refused.stderr
    assert "trained_properties differ" in refused.stderr and refused.stderr.rstrip().endswith(
        "--properties-from K"
    )
    assert script("-o", tmp_path / "soup.pt", "--properties-from", "3").returncode == 2
    assert not (tmp_path / "soup.pt").exists()
    chosen = script("-o", tmp_path / "soup.pt", "--properties-from", "2")
    assert chosen.returncode == 0, chosen.stderr
    recorded = read_checkpoint_payload(tmp_path / "soup.pt")["trained_properties"]
    assert recorded == read_checkpoint_payload(pair[1])["trained_properties"]


def test_predicted_motion_does_not_change_when_the_whole_scene_moves(box_file):
    trainer = make_trainer(box_file, TINY, _config(steps=3))
    trainer.run()
    simulator, scene = trainer.simulator.eval(), trainer.scenes[0]
    positions, quaternions = scene.positions[:3], scene.quaternions[:3]
    here = simulator.step(scene.geometry, positions, quaternions)
    offset = np.array([1000.0, -1000.0, 50.0])
    there = simulator.step(scene.geometry, positions + offset, quaternions)
    np.testing.assert_allclose(there[0] - offset, here[0], atol=1e-4)  # float32 features: 0.1 mm at 1 km
    np.testing.assert_allclose(there[1], here[1], atol=1e-5)


def test_huber_loss_is_quadratic_near_zero_and_linear_for_spikes():
    from fignetctl.core.model.training import regression_loss
    from fignetctl.errors import FignetError

    config = TrainingSettings(loss="huber", huber_delta=1.0)
    zero = torch.zeros(4, 3)
    small, spike = torch.full((4, 3), 0.1), torch.full((4, 3), 10.0)
    assert regression_loss(small, zero, config).item() == pytest.approx(0.5 * 0.01)
    assert regression_loss(spike, zero, config).item() == pytest.approx(10.0 - 0.5)
    assert regression_loss(spike, zero, TrainingSettings()).item() == pytest.approx(100.0)
    with pytest.raises(FignetError, match="unknown loss"):
        regression_loss(small, zero, TrainingSettings(loss="l1"))


def test_velocity_weight_weighs_the_velocity_columns_against_the_position_columns():
    from fignetctl.core.model.training import regression_loss

    zero = torch.zeros(5, 6)
    position_error, velocity_error = zero.clone(), zero.clone()
    position_error[:, :3], velocity_error[:, 3:] = 2.0, 2.0  # squared: 4 on half the columns
    for loss in ("mse", "huber"):
        plain = regression_loss(position_error, zero, TrainingSettings(loss=loss)).item()
        assert regression_loss(velocity_error, zero, TrainingSettings(loss=loss)).item() == pytest.approx(
            plain
        )
        weighted = TrainingSettings(loss=loss, velocity_weight=9.0)  # columns weigh 0.2 and 1.8
        assert regression_loss(position_error, zero, weighted).item() == pytest.approx(0.2 * plain)
        assert regression_loss(velocity_error, zero, weighted).item() == pytest.approx(1.8 * plain)
    rows = torch.tensor([0.0, 1.0, 2.0, 0.0, 1.0])  # row weights multiply with the column weights
    both = regression_loss(velocity_error, zero, TrainingSettings(velocity_weight=9.0), rows).item()
    assert both == pytest.approx(1.8 * 2.0 * float(rows.mean()))
    with pytest.raises(FignetError, match="six output columns"):
        regression_loss(torch.ones(5, 3), torch.zeros(5, 3), TrainingSettings(velocity_weight=9.0))


def test_a_velocity_weight_is_refused_for_a_positions_state_model(box_file):
    from fignetctl.core.model.training import make_trainer

    config = dataclasses.replace(TINY, state="positions")
    with pytest.raises(FignetError, match="velocity-state model"):
        make_trainer(box_file, config, TrainingSettings(steps=1, velocity_weight=4.0))


def test_tiny_model_overfits_with_the_huber_loss(box_file):
    trainer = make_trainer(
        box_file,
        TINY,
        _config(
            steps=300,
            loss="huber",
            noise_translation_std=0.0,
            noise_rotation_std=0.0,
            normalizer_accumulation_steps=20,
        ),
    )
    trainer.run()
    losses = [h["loss"] for h in trainer.history]
    assert np.mean(losses[-20:]) < np.mean(losses[:20]) / 10


@pytest.mark.parametrize("keeps_noise, factor", [(True, 1.0), (False, 2.0)])
def test_the_target_undoes_velocity_noise_only_when_it_keeps_the_noise(tmp_path, keeps_noise, factor):
    """A box at rest (three equal frames) jittered at t: the target is −(the jitter of each
    vertex) when the target keeps the noise (the object stops), −2× it otherwise."""
    from fignetctl.core.model.training import training_example

    resting = box_drop_file(frames=3, spin=0.0)
    for trajectory in resting.trajectories.values():
        trajectory.positions[:] = trajectory.positions[1]
    path = write_trajectories(tmp_path / "rest.h5", resting)
    config = _config(target_keeps_noise=keeps_noise, noise_translation_std=0.01, noise_rotation_std=0.01)
    trainer = make_trainer(path, TINY, config)
    scene = trainer.scenes[0]
    scene_graph, target = training_example(
        trainer.simulator.config, scene, 1, torch.Generator().manual_seed(0), config
    )
    clean = scene.geometry.world_vertices(
        scene.positions[1], scene.quaternions[1], scene.geometry.dynamic_vertices
    )
    jitter = scene_graph.dynamic_vertex_positions[1] - clean
    assert np.abs(jitter).max() > 1e-3
    np.testing.assert_allclose(target.numpy(), -factor * jitter, atol=1e-6)


def test_init_from_starts_a_new_run_from_a_models_weights(box_file, tmp_path):
    first = make_trainer(box_file, TINY, _config())
    first.run(tmp_path / "first.pt")
    tuned = make_trainer(
        box_file,
        dataclasses.replace(TINY, graph=GraphConfig(0.1, False, speculative=True)),
        _config(),
        init_from=tmp_path / "first.pt",
    )
    assert tuned.step == 0 and tuned.simulator.config.graph.speculative
    for name, value in first.simulator.state_dict().items():
        torch.testing.assert_close(tuned.simulator.state_dict()[name], value, rtol=0, atol=0)
    stored_count = first.simulator.acceleration_normalizer.count.item()
    tuned.train_step()  # its first steps add to the file's normalizer sums
    assert tuned.simulator.acceleration_normalizer.count.item() > stored_count > 0
    wider = dataclasses.replace(TINY, network=dataclasses.replace(TINY.network, latent_size=16))
    with pytest.raises(FignetError, match="network differs"):
        make_trainer(box_file, wider, _config(), init_from=tmp_path / "first.pt")
    log_mass = dataclasses.replace(TINY, graph=GraphConfig(0.1, False, log_mass=True))
    with pytest.raises(FignetError, match=r"`mass_feature` \(kg\)"):
        make_trainer(box_file, log_mass, _config(), init_from=tmp_path / "first.pt")


def test_a_fignet_from_a_fignet_star_starts_with_its_surface_edges_shut_out(box_file, tmp_path):
    star = make_trainer(box_file, TINY, _config())
    star.run(tmp_path / "star.pt")
    fignet_config = dataclasses.replace(TINY, graph=GraphConfig(0.1, True))
    fignet = make_trainer(box_file, fignet_config, _config(), init_from=tmp_path / "star.pt")
    weights, source = fignet.simulator.state_dict(), star.simulator.state_dict()
    latent = TINY.network.latent_size
    columns = slice(3 * latent, 4 * latent)  # node, face_face, mesh_to_object | node_node | object_to_mesh
    for name, value in source.items():
        if name.endswith("node_update.0.0.weight"):
            torch.testing.assert_close(weights[name][:, : 3 * latent], value[:, : 3 * latent], rtol=0, atol=0)
            torch.testing.assert_close(weights[name][:, 4 * latent :], value[:, 3 * latent :], rtol=0, atol=0)
            assert not weights[name][:, columns].any()
        else:
            torch.testing.assert_close(weights[name], value, rtol=0, atol=0)
    assert fignet.batches[0]["graph"].edge_sets["node_node"].num_edges > 0
    fresh = make_trainer(box_file, TINY, _config(), init_from=tmp_path / "star.pt")
    fignet.simulator.train(), fresh.simulator.train()
    # the same examples: the surface edges' messages are shut out, so the loss is the FIGNet*'s ...
    assert fignet.train_step() == pytest.approx(fresh.train_step(), rel=1e-6)
    for block in fignet.simulator.network.processor:  # ... and they are let in from there
        assert block.node_update[0][0].weight[:, columns].abs().max() > 0
    fignet.run(tmp_path / "fignet.pt")
    with pytest.raises(FignetError, match="network differs"):  # not the other way round
        make_trainer(box_file, TINY, _config(), init_from=tmp_path / "fignet.pt")


def test_init_from_a_model_of_fewer_blocks_adds_blocks_that_start_as_identity(box_file, tmp_path):
    first = make_trainer(box_file, TINY, _config())
    first.run(tmp_path / "first.pt")
    deeper = dataclasses.replace(TINY, network=dataclasses.replace(TINY.network, message_passing_steps=4))
    same, grown = (
        make_trainer(box_file, config, _config(), init_from=tmp_path / "first.pt")
        for config in (TINY, deeper)
    )
    assert len(grown.simulator.network.processor) == 4
    for name, value in first.simulator.state_dict().items():  # the source's blocks come first
        torch.testing.assert_close(grown.simulator.state_dict()[name], value, rtol=0, atol=0)
    added = [p for k in (2, 3) for p in grown.simulator.network.processor[k].parameters()]
    assert any(p.abs().sum() > 0 for p in added)  # the MLPs keep their random weights ...
    batch = same.batches[0]
    same.simulator.train(), grown.simulator.train()
    assert grown.train_step(batch) == same.train_step(batch)  # ... but the blocks add nothing yet
    scales = [grown.simulator.network.processor[k].node_update[1].layer_norm.weight for k in (2, 3)]
    assert all(scale.abs().max() > 0 for scale in scales)  # and they grow from there
    assert grown.config.added_blocks_from == 2 and len(grown.optimizer.param_groups) == 1
    fewer = dataclasses.replace(TINY, network=dataclasses.replace(TINY.network, message_passing_steps=1))
    wider = dataclasses.replace(deeper, network=dataclasses.replace(deeper.network, latent_size=16))
    for config in (fewer, wider):
        with pytest.raises(FignetError, match="network differs"):
            make_trainer(box_file, config, _config(), init_from=tmp_path / "first.pt")


def test_init_from_a_model_of_narrower_hidden_layers_starts_from_its_predictions(box_file, tmp_path):
    first = make_trainer(box_file, TINY, _config())
    first.run(tmp_path / "first.pt")
    hidden, wide = TINY.network.mlp_hidden_size, 2 * TINY.network.mlp_hidden_size + 3  # no other width
    wider = dataclasses.replace(TINY, network=dataclasses.replace(TINY.network, mlp_hidden_size=wide))
    same, grown = (
        make_trainer(box_file, config, _config(), init_from=tmp_path / "first.pt") for config in (TINY, wider)
    )
    source, weights = first.simulator.state_dict(), grown.simulator.state_dict()
    last_layers = 0
    for name, value in source.items():  # the source's units keep their weights, in the corner
        grown_value = weights[name]
        torch.testing.assert_close(
            grown_value[tuple(slice(0, n) for n in value.shape)], value, rtol=0, atol=0
        )
        if value.dim() == 2 and value.shape[1] == hidden:  # they read nothing of the added units
            assert not grown_value[: value.shape[0], hidden:].any()
            last_layers += value.shape[0] != hidden
        if value.dim() == 2 and grown_value.shape[0] == wide:  # which have random weights
            assert grown_value[hidden:].abs().min() > 0
    assert last_layers > 0
    batch = same.batches[0]
    same.simulator.train(), grown.simulator.train()
    assert grown.train_step(batch) == pytest.approx(same.train_step(batch), rel=1e-5)
    decoder_output = grown.simulator.network.decoder[-1].weight
    assert decoder_output[:, hidden:].abs().max() > 0  # the added units are let in from there
    grown.run(tmp_path / "wider.pt")
    with pytest.raises(FignetError, match="network differs.*size mismatch for network"):  # not narrower
        make_trainer(box_file, TINY, _config(), init_from=tmp_path / "wider.pt")


def test_the_added_blocks_learn_at_their_own_rate_and_keep_it_on_resume(box_file, tmp_path):
    make_trainer(box_file, TINY, _config()).run(tmp_path / "first.pt")
    deeper = dataclasses.replace(TINY, network=dataclasses.replace(TINY.network, message_passing_steps=4))
    config = _config(steps=4, added_blocks_learning_rate_scale=30.0)
    trainer = make_trainer(box_file, deeper, config, init_from=tmp_path / "first.pt")
    trainer.train_step()
    first, added = trainer.optimizer.param_groups
    assert added["lr"] == pytest.approx(30 * first["lr"])
    ids = {id(p) for p in added["params"]}
    assert ids == {id(p) for k in (2, 3) for p in trainer.simulator.network.processor[k].parameters()}
    assert len(first["params"]) + len(ids) == len(list(trainer.simulator.parameters()))
    scales = [trainer.simulator.network.processor[k].node_update[1].layer_norm.weight for k in (2, 3)]
    assert all(scale.abs().max() > 10 * config.learning_rate_initial for scale in scales)  # ~30 lr a step
    trainer.run(tmp_path / "grown.pt")
    resumed = make_trainer(box_file, deeper, _config(steps=6), resume_from=tmp_path / "grown.pt")
    assert resumed.config.added_blocks_from == 2 and resumed.config.added_blocks_learning_rate_scale == 30
    assert len(resumed.optimizer.param_groups) == 2
    resumed.run(tmp_path / "grown.pt")
    with pytest.raises(FignetError, match="blocks added to a trained model"):
        make_trainer(box_file, TINY, config, init_from=tmp_path / "first.pt")


def test_a_run_saved_before_target_keeps_noise_resumes_with_its_old_target(box_file, tmp_path):
    import json

    trainer = make_trainer(box_file, TINY, _config(target_keeps_noise=False))
    trainer.run(tmp_path / "old.pt", until_step=4)
    payload = torch.load(tmp_path / "old.pt", weights_only=True)
    stored = json.loads(payload["training_state"]["training_config"])
    del stored["target_keeps_noise"]
    payload["training_state"]["training_config"] = json.dumps(stored)
    torch.save(payload, tmp_path / "old.pt")
    resumed = make_trainer(box_file, TINY, _config(), resume_from=tmp_path / "old.pt")
    assert resumed.config.target_keeps_noise is False


def test_network_threads_leave_the_workers_their_cores(monkeypatch):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(6)), raising=False)
    before = torch.get_num_threads()
    with network_threads(2, "cpu"):
        assert torch.get_num_threads() == 4
    with network_threads(8, "cpu"):  # more workers than cores: still one thread
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    monkeypatch.setenv("OMP_NUM_THREADS", "3")  # as torchrun sets it: kept
    with network_threads(1, "cpu"):
        assert torch.get_num_threads() == before


def _heap_blocks(size, count):
    """`count` blocks of `size` bytes (under glibc's mmap threshold, so on the heap), written
    to; all but the last freed, which keeps the heap's top in use. Returns a function that
    frees the last one."""
    import ctypes

    libc = ctypes.CDLL(None)
    libc.malloc.restype = ctypes.c_void_p
    libc.free.argtypes = [ctypes.c_void_p]
    blocks = [libc.malloc(size) for _ in range(count)]
    for block in blocks:
        ctypes.memset(block, 1, size)
    for block in blocks[:-1]:
        libc.free(block)
    return lambda: libc.free(blocks[-1])


GLIBC_ON_LINUX = pytest.mark.skipif(
    _malloc_trim() is None or resident_bytes() is None, reason="glibc's malloc_trim and /proc"
)


@GLIBC_ON_LINUX
def test_freed_heap_blocks_go_back_to_the_system():
    """Blocks freed below a live one stay resident until `return_freed_memory` hands them back,
    as a trainer's graphs of changing sizes did."""
    size, count = 100_000, 300
    free_last = _heap_blocks(size, count)
    kept = resident_bytes()
    return_freed_memory()
    returned = kept - resident_bytes()
    free_last()
    assert returned > 0.8 * size * (count - 1)


@GLIBC_ON_LINUX
def test_the_heap_is_trimmed_only_when_memory_grew_past_its_limit():
    heap = HeapTrimmer(growth=1.05)
    assert not heap.step()  # the first step sets the limit
    limit = heap.limit
    assert limit > resident_bytes() and not heap.step() and heap.limit == limit  # no growth since
    size = 100_000
    free_last = _heap_blocks(size, int(0.2 * limit / size))  # 20 % more, freed but resident
    grown = resident_bytes()
    assert grown > limit and heap.step()
    assert resident_bytes() < grown - 0.1 * limit and heap.limit == limit
    free_last()


REUSED_BLOCK_FAULTS = """
import ctypes, resource, sys
from fignetctl.core.model.training import keep_heap_pages
if sys.argv[1] == "keep":
    assert keep_heap_pages()
libc = ctypes.CDLL(None)
libc.malloc.restype, libc.malloc.argtypes, libc.free.argtypes = ctypes.c_void_p, [ctypes.c_size_t], [ctypes.c_void_p]
def step(size=64 << 20):  # a tensor of 64 MB, written and freed, as a step's activations
    block = libc.malloc(size)
    ctypes.memset(block, 1, size)
    libc.free(block)
step()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(3):
    step()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


@GLIBC_ON_LINUX
def test_kept_heap_pages_serve_a_freed_large_block_again_without_page_faults():
    """The kernel's count of page faults: with glibc's defaults each 64 MB block is mapped
    afresh, every page faulted in; after `keep_heap_pages` the freed block's pages are reused."""
    import subprocess
    import sys

    def faults(mode):
        run = subprocess.run(
            [sys.executable, "-c", REUSED_BLOCK_FAULTS, mode], capture_output=True, text=True, check=False
        )
        assert run.returncode == 0, run.stderr
        return int(run.stdout)

    pages = 3 * (64 << 20) // os.sysconf("SC_PAGE_SIZE")
    default, kept = faults("default"), faults("keep")
    assert default > 0.5 * pages
    assert kept < 0.05 * pages


def _descendants(pid):
    """The pids of every process below `pid` (Linux /proc)."""
    children = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit() and (fields := _stat(int(entry))):
            children.setdefault(int(fields[1]), []).append(int(entry))
    found, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads processes from /proc")
def test_killing_the_trainer_ends_its_graph_workers(box_file, tmp_path):
    import signal
    import subprocess
    import sys
    import time

    command = [sys.executable, "-c", "from fignetctl.cli import main; main()", "train", str(box_file)]
    command += ["-o", str(tmp_path / "m.pt"), "--size", "tiny", "--steps", "1000000", "--workers", "1"]
    trainer = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while len(below := _descendants(trainer.pid)) < 2 and time.monotonic() < deadline:
            time.sleep(0.2)  # the worker is a grandchild: trainer -> fork server -> worker
        assert trainer.poll() is None and len(below) >= 2, "the trainer did not start a graph worker"
        time.sleep(1.0)  # the worker has run its init function by now
        below = _descendants(trainer.pid)
        trainer.send_signal(signal.SIGKILL)  # as the out-of-memory killer does: no clean-up runs
        trainer.wait()
        deadline = time.monotonic() + 30
        while (alive := [p for p in below if _running(p)]) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert alive == [], f"processes of the killed trainer still run: {alive}"
    finally:
        if trainer.poll() is None:
            trainer.kill()


def _stat(pid):
    """The fields of /proc/PID/stat after the command name (state, parent pid, ...), or None
    once the process is gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None


def _running(pid):
    """False once it has ended, also as a zombie (not yet reaped by its new parent)."""
    fields = _stat(pid)
    return fields is not None and fields[0] != "Z"


@pytest.mark.parametrize("pidfd", [True, False])
def test_a_worker_ends_soon_after_the_process_it_watches(pidfd):
    import subprocess
    import sys

    watched = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    code = "\n".join(
        [
            "import os, time",
            "" if pidfd else "del os.pidfd_open  # as where there is none: look every second",
            "from fignetctl.core.model.training import end_with_process",
            f"end_with_process({watched.pid})",
            "print('watching', flush=True)",
            "time.sleep(60)",
        ]
    )
    worker = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert worker.stdout.readline() == "watching\n"
        watched.kill()
        watched.wait()
        assert worker.wait(timeout=30) == 1  # ended by the watcher (os._exit(1)), not after its sleep
    finally:
        watched.kill()
        worker.kill()


def test_a_run_with_inertia_from_a_model_without_it_starts_where_the_model_is(box_file, tmp_path):
    plain = make_trainer(box_file, TINY, _config())
    plain.run(tmp_path / "plain.pt")
    with_inertia = dataclasses.replace(TINY, graph=GraphConfig(0.1, False, inertia=True))
    grafted = make_trainer(box_file, with_inertia, _config(), init_from=tmp_path / "plain.pt")
    weights, source = grafted.simulator.state_dict(), plain.simulator.state_dict()
    first_layer = "network.node_encoder.0.0.weight"
    torch.testing.assert_close(weights[first_layer][:, :12], source[first_layer], rtol=0, atol=0)
    assert weights[first_layer].shape[1] == 21 and not weights[first_layer][:, 12:].any()
    normalizer = grafted.simulator.node_normalizer
    torch.testing.assert_close(normalizer.sum[:12], source["node_normalizer.sum"], rtol=0, atol=0)
    # the added columns' statistics are those of the nodes' inertia: a box's I/m on object nodes
    rows = grafted.batches[0]["graph"].node_features[:, 12:].double()
    torch.testing.assert_close(normalizer.mean()[12:], rows.mean(0), rtol=0.05, atol=1e-4)
    assert normalizer.std()[[12, 16, 20]].min() > 1e-3
    fresh = make_trainer(box_file, TINY, _config(), init_from=tmp_path / "plain.pt")
    grafted.simulator.train(), fresh.simulator.train()
    # the same examples and predictions: the loss is the source's, and the columns open from there
    assert grafted.train_step() == pytest.approx(fresh.train_step(), rel=1e-6)
    assert grafted.simulator.network.node_encoder[0][0].weight[:, 12:].abs().max() > 0
    grafted.run(tmp_path / "inertia.pt")
    with pytest.raises(FignetError, match="trained with `inertia`"):  # not the other way round
        make_trainer(box_file, TINY, _config(), init_from=tmp_path / "inertia.pt")
