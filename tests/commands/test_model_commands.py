import dataclasses
import json

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from fignetctl.cli import cli
from fignetctl.core.provenance import file_sha256, read_provenance
from fignetctl.core.trajectory import read_trajectories, write_trajectories
from tests.conftest import box_drop_file
from tests.rerun_reading import SavingViewer, dead_address, read_recording, rerun_executable


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    folder = tmp_path_factory.mktemp("model")
    data = write_trajectories(
        folder / "box.h5", box_drop_file(frames=80, height=5.0)
    )  # stays above the floor for 50 steps
    model = folder / "model.pt"
    result = CliRunner().invoke(
        cli,
        [
            "train",
            str(data),
            "-o",
            str(model),
            "--size",
            "tiny",
            "--steps",
            "6",
            "--checkpoint-every",
            "3",
            "--log-csv",
            str(folder / "loss.csv"),
        ],
    )
    assert result.exit_code == 0, result.output
    return folder, data, model


def test_train_writes_model_and_loss_log(trained):
    folder, _, model = trained
    assert model.is_file()
    rows = (folder / "loss.csv").read_text().splitlines()
    assert rows[0] == "step,loss,seconds" and len(rows) == 7


def test_train_learning_rate_option_sets_the_schedule(trained, tmp_path):
    from fignetctl.core.model.checkpoint import read_checkpoint_payload

    _, data, model = trained
    out = tmp_path / "tuned.pt"
    args = [
        "train",
        str(data),
        "-o",
        str(out),
        "--size",
        "tiny",
        "--steps",
        "2",
        "--init-from",
        str(model),
        "--learning-rate",
        "2e-4",
        "2e-5",
    ]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    state = read_checkpoint_payload(out)["training_state"]
    config = json.loads(state["training_config"])
    assert (config["learning_rate_initial"], config["learning_rate_final"]) == (2e-4, 2e-5)
    assert state["optimizer"]["param_groups"][0]["lr"] == pytest.approx(
        2e-4 * 0.1**0.5
    )  # the second of two steps: halfway down
    result = CliRunner().invoke(cli, args[:-3] + ["--learning-rate", "0", "1e-4", "--overwrite"])
    assert result.exit_code == 2 and "--learning-rate" in result.output


def test_train_noise_option_sets_the_jitter_and_refuses_negative_or_nan(trained, tmp_path):
    from fignetctl.core.model.checkpoint import read_checkpoint_payload
    from fignetctl.errors import SettingError
    from fignetctl.stages import train as stage

    _, data, _ = trained
    out = tmp_path / "noisy.pt"
    args = ["train", str(data), "-o", str(out), "--size", "tiny", "--steps", "1"]
    result = CliRunner().invoke(cli, [*args, "--noise", "0.01", "0.02"])
    assert result.exit_code == 0, result.output
    config = json.loads(read_checkpoint_payload(out)["training_state"]["training_config"])
    assert (config["noise_translation_std"], config["noise_rotation_std"]) == (0.01, 0.02)
    refused = CliRunner().invoke(cli, [*args, "--noise", "-0.01", "0", "--overwrite"])
    assert refused.exit_code == 2 and "--noise" in refused.output
    with pytest.raises(SettingError, match="noise"):
        stage.run(data, tmp_path / "nan.pt", stage.Settings(size="tiny", steps=1, noise=(0.01, float("nan"))))
    assert not (tmp_path / "nan.pt").exists()


@pytest.mark.parametrize(
    "option, field, refusal",
    [
        (["--mass-feature", "log"], "log_mass", "give the same --mass-feature (kg)"),
        (
            ["--contact-velocity"],
            "contact_velocity",
            "trained without --contact-velocity; give this run the same",
        ),
    ],
)
def test_train_feature_options_reach_the_model_file(trained, tmp_path, option, field, refusal):
    """A new input feature is recorded, and a model without it cannot seed a run with it."""
    from fignetctl.core.model.checkpoint import load_checkpoint

    _, data, model = trained
    assert getattr(load_checkpoint(model).config.graph, field) is False
    out = tmp_path / "featured.pt"
    args = ["train", str(data), "-o", str(out), "--size", "tiny", "--steps", "2", *option]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert getattr(load_checkpoint(out).config.graph, field) is True
    result = CliRunner().invoke(cli, [*args[:4], "--init-from", str(model), "--overwrite", *args[4:]])
    assert result.exit_code == 1 and refusal in result.output
    assert "Traceback" not in result.output


def test_train_inertia_grows_a_model_without_it_whose_run_rolls_out_and_is_not_shrunk_back(trained, tmp_path):
    """--inertia is recorded; a model without it seeds a run with it (zero input columns), the
    result rolls out, and a model with it cannot seed a run without it."""
    from fignetctl.core.model.checkpoint import load_checkpoint

    _, data, model = trained
    out = tmp_path / "inertia.pt"
    args = ["train", str(data), "-o", str(out), "--size", "tiny", "--steps", "2", "--init-from", str(model)]
    result = CliRunner().invoke(cli, [*args, "--inertia"])
    assert result.exit_code == 0, result.output
    assert load_checkpoint(out).config.graph.inertia and not load_checkpoint(model).config.graph.inertia
    rolled = tmp_path / "rolled.h5"
    result = CliRunner().invoke(
        cli, ["rollout", str(data), "--model", str(out), "--steps", "3", "-o", str(rolled)]
    )
    assert result.exit_code == 0, result.output
    assert np.isfinite(read_trajectories(rolled).trajectories["00000"].positions).all()
    args[-1] = str(out)
    result = CliRunner().invoke(cli, [*args[:3], str(tmp_path / "shrunk.pt"), *args[4:]])
    assert result.exit_code == 1 and "trained with --inertia; give this run the same" in result.output
    assert "Traceback" not in result.output


def test_train_free_motion_reaches_the_model_file_and_needs_the_velocity_state(trained, tmp_path):
    """--free-motion is recorded, a model without it cannot seed a run with it, and a two-frame
    model cannot have it (it carries no velocity to fly on)."""
    from fignetctl.core.model.checkpoint import load_checkpoint

    _, data, model = trained
    out = tmp_path / "free.pt"
    args = ["train", str(data), "-o", str(out), "--size", "tiny", "--steps", "2", "--free-motion"]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert load_checkpoint(out).config.free_motion and not load_checkpoint(model).config.free_motion
    result = CliRunner().invoke(cli, [*args, "--init-from", str(model), "--overwrite"])
    assert result.exit_code == 1 and "trained without --free-motion; give this run the same" in result.output
    result = CliRunner().invoke(cli, [*args, "--state", "positions", "--overwrite"])
    assert result.exit_code != 0 and "--state velocities" in result.output
    assert "Traceback" not in result.output


def test_train_decimation_option_reaches_the_model_file(trained, tmp_path):
    from fignetctl.core.model.checkpoint import load_checkpoint

    _, data, model = trained
    assert load_checkpoint(model).config.decimation == "closest"
    out = tmp_path / "quadric.pt"
    args = ["train", str(data), "-o", str(out), "--size", "tiny", "--steps", "2", "--decimation", "quadric"]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert load_checkpoint(out).config.decimation == "quadric"


def test_train_refuses_existing_output_and_resumes_on_request(trained):
    _folder, data, model = trained
    result = CliRunner().invoke(cli, ["train", str(data), "-o", str(model), "--size", "tiny", "--steps", "8"])
    assert result.exit_code == 2 and "--overwrite" in result.output
    result = CliRunner().invoke(
        cli,
        [
            "train",
            str(data),
            "-o",
            str(model),
            "--size",
            "tiny",
            "--steps",
            "8",
            "--resume",
            "--checkpoint-every",
            "3",
        ],
    )
    assert result.exit_code == 0, result.output


def test_train_stops_at_its_time_limit_with_exit_75_and_resume_finishes(tmp_path):
    data = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=12))
    model = tmp_path / "model.pt"
    args = ["train", str(data), "-o", str(model), "--size", "tiny", "--steps", "3", "--resume"]
    args += [
        "--frame-sampling",
        "motion",
        "--calm-weight",
        "2",
        "--rest-weight",
        "30",
        "--undo-position-noise",
        "0.3",
        "--velocity-weight",
        "4",
        "--unroll",
        "2",
    ]
    stopped = CliRunner().invoke(cli, [*args, "--time-limit", "1e-9"])
    assert stopped.exit_code == 75, stopped.output
    assert "stopped at the time limit after step 1 of 3" in stopped.output and "--resume" in stopped.output
    assert torch.load(model, weights_only=True)["training_state"]["step"] == 1
    finished = CliRunner().invoke(cli, args)
    assert finished.exit_code == 0 and finished.output.strip().endswith(str(model)), finished.output
    state = torch.load(model, weights_only=True)["training_state"]
    stored = json.loads(state["training_config"])
    assert state["step"] == 3 and stored["frame_sampling"] == "motion" and stored["calm_weight"] == 2
    assert (
        stored["rest_weight"] == 30
        and stored["position_noise_undone"] == 0.3
        and stored["velocity_weight"] == 4
    )
    assert stored["unroll"] == 2
    refused = CliRunner().invoke(cli, [*args, "--time-limit", "0"])
    assert refused.exit_code == 2 and "--time-limit" in refused.output


def test_a_time_limited_run_from_init_from_says_to_resume_without_it(tmp_path):
    data = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=12))
    first, second = tmp_path / "first.pt", tmp_path / "second.pt"
    base = ["train", str(data), "--size", "tiny", "--steps", "3"]
    assert CliRunner().invoke(cli, [*base, "-o", str(first)]).exit_code == 0
    args = [*base, "-o", str(second)]
    stopped = CliRunner().invoke(cli, [*args, "--init-from", str(first), "--time-limit", "1e-9"])
    assert stopped.exit_code == 75, stopped.output
    assert "--resume in place of --init-from" in stopped.output
    finished = CliRunner().invoke(cli, [*args, "--resume"])
    assert finished.exit_code == 0, finished.output
    assert torch.load(second, weights_only=True)["training_state"]["step"] == 3


def test_rollout_keeps_scene_frames_and_appends_steps(trained, tmp_path):
    _, data, model = trained
    out = tmp_path / "rollout.h5"
    rrd = tmp_path / "rollout.rrd"
    result = CliRunner().invoke(
        cli,
        ["rollout", str(data), "--model", str(model), "--steps", "5", "-o", str(out), "--rerun", str(rrd)],
    )
    assert result.exit_code == 0, result.output
    recording = read_recording(rrd)  # the rolled-out trajectory, frame by frame, as `show` logs it
    assert recording.entities_under("world/objects") == ["world/objects/00_floor", "world/objects/01_box"]
    for entity in recording.entities_under("world/objects"):
        assert "Mesh3D:vertex_positions" in recording.components(entity)
        assert recording.times(entity, "frame") == list(range(7)) and recording.rows(entity) == 7
    assert recording.entities_under("world/traces") == ["world/traces/01_box"]
    assert recording.times("world/plots/energy/total", "frame") == list(range(7))
    rolled = read_trajectories(out).trajectories["00000"]
    truth = read_trajectories(data).trajectories["00000"]
    assert rolled.positions.shape == (7, 2, 3)
    made_from = read_provenance(out)["inputs_sha256"]  # which model and scene made it
    assert made_from == {"model": file_sha256(model), "scene": file_sha256(data)}
    np.testing.assert_array_equal(rolled.positions[:2], truth.positions[:2])
    np.testing.assert_array_equal(
        rolled.positions[:, 0], truth.positions[:7, 0]
    )  # the static floor follows its frames


def test_model_file_dataset_and_report_say_what_made_them(trained, tmp_path):
    from fignetctl import __version__

    _, data, model = trained
    assert read_provenance(model) == {
        "fignetctl_version": __version__,
        "inputs_sha256": {"training_data": file_sha256(data)},
    }
    assert read_provenance(data) == {"fignetctl_version": __version__, "inputs_sha256": {}}
    out = tmp_path / "metrics.json"
    args = ["evaluate", str(data), "--model", str(model), "--max-trajectories", "1", "-o", str(out)]
    assert CliRunner().invoke(cli, args).exit_code == 0
    assert read_provenance(out) == {
        "fignetctl_version": __version__,
        "inputs_sha256": {"data": file_sha256(data), "model": file_sha256(model)},
    }


def test_evaluate_reports_model_and_baselines(trained, tmp_path):
    _, data, model = trained
    out = tmp_path / "metrics.json"
    result = CliRunner().invoke(
        cli, ["evaluate", str(data), "--model", str(model), "--with-guards", "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())
    metrics = report["metrics"]
    assert set(metrics) == {"model", "model_with_guards", "constant_velocity", "stand_still"}
    assert (
        metrics["model_with_guards"]["50_steps"]["all"]["translation_rmse_m"] < 1e-3
    )  # free flight: exact while the box falls
    # physical horizons at the file's 60 fps: 0.1 s = 6 steps, ..., 1 s = 60 steps; 1.67 s and 2 s are past its 80 frames
    assert sorted(metrics["stand_still"]) == sorted(
        ["50_steps", "0.1_seconds", "0.2_seconds", "0.33_seconds", "0.5_seconds", "1_seconds"]
    )
    half_second = metrics["stand_still"]["0.5_seconds"]["all"]
    assert half_second["translation_rmse_m"] == pytest.approx(
        0.5 * 10 * ((31 / 60) ** 2 - (1 / 60) ** 2), rel=1e-3
    )
    assert half_second["rotation_rms_deg"] >= half_second["rotation_error_deg"] > 0
    falling = metrics["stand_still"]["50_steps"]["all"]["translation_rmse_m"]
    assert falling == pytest.approx(0.5 * 10 * ((51 / 60) ** 2 - (1 / 60) ** 2), rel=1e-3)
    assert (
        metrics["constant_velocity"]["50_steps"]["all"]["translation_rmse_m"] < 1e-3
    )  # free fall is ballistic
    assert "box" in metrics["model"]["50_steps"]["per_shape"]
    # the box falls freely the whole time: every horizon's error is the calm objects'
    motions = metrics["model"]["50_steps"]["per_motion"]
    assert (
        list(motions) == ["calm"]
        and motions["calm"]["objects"] == metrics["model"]["50_steps"]["all"]["objects"]
    )
    curve = report["curves"]["stand_still"]  # every step k: the box has fallen g((k+1)² − 1)dt²/2
    steps = np.array(curve["step"])
    np.testing.assert_array_equal(steps, np.arange(1, 61))  # to the longest horizon inside 80 frames: 1 s
    np.testing.assert_allclose(
        curve["translation_rmse_m"], 0.5 * 10 * ((steps + 1) ** 2 - 1) / 60**2, rtol=1e-3
    )
    assert (
        report["curves"]["model"]["translation_rmse_m"][49]
        == metrics["model"]["50_steps"]["all"]["translation_rmse_m"]
    )
    versus_stand_still = report["comparison"]["stand_still"]["50_steps"]
    model_error = metrics["model"]["50_steps"]["all"]["translation_rmse_m"]
    assert versus_stand_still["translation_rmse_ratio"] == pytest.approx(model_error / falling)
    assert versus_stand_still["objects"] == 1 and versus_stand_still["trajectories"] == 1


def test_max_faces_decimates_the_meshes_the_model_reads_and_is_recorded(trained, tmp_path):
    """--max-faces changes the scene the network reads (the box's 12 faces cut to 6), not the
    network; rollout's file and evaluate's json say what it was. Fewer than 4 faces is refused."""
    _, data, model = trained
    rolled = {}
    for faces in (None, 6):
        out = tmp_path / f"rollout-{faces}.h5"
        args = [
            "rollout",
            str(data),
            "--model",
            str(model),
            "--steps",
            "3",
            "--no-free-flight",
            "-o",
            str(out),
        ]
        result = CliRunner().invoke(cli, args + ([] if faces is None else ["--max-faces", str(faces)]))
        assert result.exit_code == 0, result.output
        written = read_trajectories(out)
        assert json.loads(written.attrs["model_config"])["max_faces_per_object"] == (faces or 256)
        rolled[faces] = written.trajectories["00000"].positions[2:, 1]
    assert np.abs(rolled[None] - rolled[6]).max() > 1e-6
    out = tmp_path / "metrics.json"
    args = ["evaluate", str(data), "--model", str(model), "-n", "1", "--max-faces", "0", "-o", str(out)]
    assert CliRunner().invoke(cli, args).exit_code == 0
    assert json.loads(out.read_text())["max_faces"] is None  # whole meshes
    for command in ("rollout", "evaluate"):
        args = [command, str(data), "--model", str(model), "--max-faces", "3", "-o", str(tmp_path / "x")]
        result = CliRunner().invoke(cli, args)
        assert result.exit_code != 0 and "at least 4 faces" in result.output
        assert "Traceback" not in result.output and not (tmp_path / "x").exists()


def test_evaluate_against_another_model_pairs_the_trajectories(trained, tmp_path):
    """Against itself the ratio is 1 with no spread; against itself on its file's meshes while
    the model reads coarser ones, the two differ; a missing model is a clear error."""
    _, data, model = trained
    out = tmp_path / "metrics.json"
    args = ["evaluate", str(data), "--model", str(model), "--against", str(model), "-o", str(out)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())
    assert report["metrics"]["against"] == report["metrics"]["model"]
    paired = report["comparison"]["against"]["50_steps"]
    assert paired["translation_rmse_ratio"] == 1.0 and paired["translation_rmse_ratio_95"] == [1.0, 1.0]
    assert paired["rotation_error_difference_deg"] == 0.0
    assert report["against"] == str(model) and read_provenance(out)["inputs_sha256"][
        "against"
    ] == file_sha256(model)
    coarser = CliRunner().invoke(cli, [*args, "--max-faces", "6", "--overwrite"])
    assert coarser.exit_code == 0, coarser.output
    paired = json.loads(out.read_text())["comparison"]["against"]["50_steps"]
    assert paired["translation_rmse_ratio"] != 1.0
    missing = CliRunner().invoke(
        cli, [*args[:-2], "--against", str(tmp_path / "none.pt"), "-o", str(tmp_path / "x.json")]
    )
    assert missing.exit_code != 0 and "none.pt" in missing.output and "Traceback" not in missing.output
    assert not (tmp_path / "x.json").exists()


def test_evaluate_ceilings_need_a_make_dataset_file(trained, tmp_path):
    _, data, model = trained  # written by the tests, not by make-dataset: no generator config
    out = tmp_path / "metrics.json"
    result = CliRunner().invoke(
        cli, ["evaluate", str(data), "--model", str(model), "--ceilings", "-o", str(out)]
    )
    assert result.exit_code != 0 and not out.exists()
    assert "not made by `fignetctl make-dataset`" in result.output and "Traceback" not in result.output


def test_free_flight_makes_a_falling_box_exact_in_rollout_and_evaluate(trained, tmp_path):
    _, data, model = trained  # the box falls freely for the first 50 steps
    truth = read_trajectories(data).trajectories["00000"].positions
    errors = {}
    for flag in ("--free-flight", "--no-free-flight"):
        out = tmp_path / f"{flag}.h5"
        result = CliRunner().invoke(
            cli, ["rollout", str(data), "--model", str(model), "--steps", "20", flag, "-o", str(out)]
        )
        assert result.exit_code == 0, result.output
        errors[flag] = np.abs(
            read_trajectories(out).trajectories["00000"].positions[:, 1] - truth[:22, 1]
        ).max()
    assert errors["--free-flight"] < 1e-4 < errors["--no-free-flight"]  # a 6-step model does not fall at g
    out = tmp_path / "metrics.json"
    result = CliRunner().invoke(
        cli, ["evaluate", str(data), "--model", str(model), "--free-flight", "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())
    assert report["free_flight"] is True
    assert report["metrics"]["model"]["50_steps"]["all"]["translation_rmse_m"] < 1e-3


def test_keep_out_stops_a_falling_box_at_the_floor(trained, tmp_path):
    import trimesh

    from fignetctl.core.transforms import transform_points

    _, data, model = trained  # the box reaches the floor at about step 55
    lowest = {}
    for flag in ("--keep-out", "--no-keep-out"):
        out = tmp_path / f"{flag}.h5"
        result = CliRunner().invoke(
            cli,
            [
                "rollout",
                str(data),
                "--model",
                str(model),
                "--steps",
                "75",
                "--no-sleep",
                flag,
                "-o",
                str(out),
            ],
        )
        assert result.exit_code == 0, result.output
        frames = read_trajectories(out).trajectories["00000"]
        corners = trimesh.creation.box().vertices
        lowest[flag] = min(
            transform_points(corners, 1.0, p, q)[:, 2].min()
            for p, q in zip(frames.positions[:, 1], frames.quaternions[:, 1])
        )
    assert lowest["--keep-out"] >= -1e-3  # float32 poses in the file; the guard's tolerance is 1 mm
    assert lowest["--no-keep-out"] < -0.05  # a 6-step model does not stop at the floor by itself
    out = tmp_path / "metrics.json"
    result = CliRunner().invoke(
        cli, ["evaluate", str(data), "--model", str(model), "--keep-out", "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    assert json.loads(out.read_text())["keep_out"] is True


@pytest.mark.parametrize("bad", ["garbage", "missing"])
def test_bad_model_file_is_one_line_error(trained, tmp_path, bad):
    _, data, _ = trained
    model = tmp_path / "model.pt"
    if bad == "garbage":
        model.write_bytes(b"PK\x03\x04 not really" * 50)
    result = CliRunner().invoke(
        cli, ["rollout", str(data), "--model", str(model), "-o", str(tmp_path / "r.h5")]
    )
    assert result.exit_code == 1
    assert "Traceback" not in result.output and result.output.startswith("Error: ")
    assert not (tmp_path / "r.h5").exists()


def test_rollout_refuses_scene_with_one_frame(trained, tmp_path):
    _, _, model = trained
    scene = write_trajectories(tmp_path / "one.h5", box_drop_file(frames=1))
    result = CliRunner().invoke(
        cli, ["rollout", str(scene), "--model", str(model), "-o", str(tmp_path / "r.h5")]
    )
    assert result.exit_code == 1 and "needs 2" in result.output


def train_briefly(data, output, *extra):
    return CliRunner().invoke(
        cli, ["train", str(data), "-o", str(output), "--size", "tiny", "--steps", "2", *map(str, extra)]
    )


def test_train_logs_loss_to_rerun(trained, tmp_path):
    _, data, _ = trained
    rrd = tmp_path / "loss.rrd"
    result = train_briefly(data, tmp_path / "m.pt", "--rerun", rrd)
    assert result.exit_code == 0, result.output
    recording = read_recording(rrd)
    assert list(recording.entities) == ["train/loss"]
    assert recording.times("train/loss", "step") == [1, 2] and recording.rows("train/loss") == 2
    assert recording.application_id == "fignetctl" and recording.recording_id == str(tmp_path.resolve())


@pytest.mark.skipif(rerun_executable() is None, reason="the rerun viewer CLI is not installed")
def test_train_streams_the_loss_to_a_running_viewer(trained, tmp_path):
    _, data, _ = trained
    with SavingViewer(tmp_path / "viewer" / "live.rrd") as viewer:
        result = train_briefly(
            data, tmp_path / "m.pt", "--rerun", tmp_path / "loss.rrd", "--rerun-connect", viewer.address
        )
        assert result.exit_code == 0, result.output
    live, saved = read_recording(viewer.path), read_recording(tmp_path / "loss.rrd")
    assert list(live.entities) == list(saved.entities) == ["train/loss"]
    assert live.times("train/loss", "step") == saved.times("train/loss", "step") == [1, 2]
    assert live.recording_id == saved.recording_id  # the viewer shows both as one recording
    assert "warning" not in result.output


def test_train_goes_on_when_no_viewer_listens(trained, tmp_path):
    _, data, _ = trained
    address = dead_address()
    result = train_briefly(data, tmp_path / "m.pt", "--rerun-connect", address)
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.stderr.splitlines() if "warning" in line]
    assert warnings == [f"warning: no rerun viewer listens at {address}; going on without live viewing"]
    assert (tmp_path / "m.pt").is_file()
    refused = train_briefly(data, tmp_path / "n.pt", "--rerun-connect", "localhost:9876")
    assert (
        refused.exit_code == 2
        and "--rerun-connect 'localhost:9876'" in refused.output
        and "Traceback" not in refused.output
    )
    assert not (tmp_path / "n.pt").exists()


def test_model_stores_the_properties_it_was_trained_on_and_rollout_warns_outside_them(
    trained, tmp_path, caplog
):
    import dataclasses

    from fignetctl.core.model.apply import load_model
    from fignetctl.core.model.checkpoint import export_checkpoint
    from fignetctl.errors import FormatError

    _, data, model = trained
    truth = read_trajectories(data).trajectories["00000"]
    ranges = load_model(str(model)).trained_properties
    assert ranges["dynamic"]["friction"] == pytest.approx([truth.friction[1]] * 2)
    assert (
        ranges["static"]["restitution"] == pytest.approx([truth.restitution[0]] * 2)
        and "mass" not in ranges["static"]
    )
    assert ranges["dynamic"]["materials"] == [pytest.approx([truth.friction[1], truth.restitution[1]])]
    assert ranges["dynamic"]["largest_side"] == pytest.approx([truth.scales[1]] * 3)  # a unit box, scaled
    scene = box_drop_file(frames=80, height=5.0)
    slippery = dataclasses.replace(
        scene.trajectories["00000"], friction=np.array([truth.friction[0], 5.0], np.float32)
    )
    write_trajectories(tmp_path / "slippery.h5", dataclasses.replace(scene, trajectories={"00000": slippery}))
    for path, warned in ((data, False), (tmp_path / "slippery.h5", True)):
        for command in (
            ["rollout", "--steps", "2", "-o", tmp_path / "r.h5"],
            ["evaluate", "-o", tmp_path / "m.json"],
        ):
            caplog.clear()
            result = CliRunner().invoke(
                cli, [command[0], str(path), "--model", str(model), *map(str, command[1:]), "--overwrite"]
            )
            assert result.exit_code == 0, result.output
            messages = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
            assert len(messages) == warned, messages
    assert (
        "dynamic object 'box' has friction 5 and restitution" in messages[0] and "extrapolates" in messages[0]
    )
    # export keeps the ranges; a run saved before them gets them from its own training file only
    assert load_model(str(export_checkpoint(model, tmp_path / "shipped.pt"))).trained_properties == ranges
    again = export_checkpoint(
        tmp_path / "shipped.pt", tmp_path / "again.pt", trained_on=data
    )  # an exported file keeps its provenance
    assert load_model(str(again)).trained_properties == ranges
    with pytest.raises(FormatError, match="is not the file"):
        export_checkpoint(model, tmp_path / "other.pt", trained_on=tmp_path / "slippery.h5")


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: box_drop_file(frames=2), "has 2 frames; training needs 3 or more"),
        (
            lambda d: dataclasses.replace(
                d,
                trajectories={
                    "00000": dataclasses.replace(
                        d.trajectories["00000"], static=np.array([True, True]), mass=np.zeros(2, np.float32)
                    )
                },
            ),
            "no trajectory has a dynamic object",
        ),
    ],
    ids=["two frames", "nothing dynamic"],
)
def test_data_with_nothing_to_learn_is_one_error_line(tmp_path, change, message):
    data = write_trajectories(tmp_path / "d.h5", change(box_drop_file(frames=5)))
    result = CliRunner().invoke(
        cli, ["train", str(data), "--size", "tiny", "--steps", "2", "-o", str(tmp_path / "m.pt")]
    )
    assert result.exit_code == 1 and message in result.output and "Traceback" not in result.output
    assert not (tmp_path / "m.pt").exists()
