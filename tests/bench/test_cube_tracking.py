"""benchmarks/cube_tracking.py: the model's rollout of its own cube trajectory beside PyBullet
restarted, and run freely after a nudge of the model's one-step error and of 1 mm."""

import argparse

import pytest

from tests.bench import load_benchmark


@pytest.mark.slow
@pytest.mark.parametrize("free_motion", [False, True])
def test_a_short_run_reports_the_model_beside_physics_at_every_horizon(free_motion):
    bench = load_benchmark("cube_tracking")
    args = argparse.Namespace(
        steps=3,
        learning_rate=[3e-3, 3e-4],
        noise=0.0,
        seed=0,
        pushforward=0,
        calm_weight=0.0,
        size="tiny",
        free_motion=free_motion,
    )
    result = bench.measure("dropped", args)
    assert result["cubes"] == 1 and 0.0 < result["fvu"]
    nudge = result["physics_nudged_by_the_models_one_step_error"]
    assert nudge["nudge_m"] == pytest.approx(result["model"][0]["translation_rmse_m"])
    for rows in (result["model"], result["physics_nudged_by_1_mm"], nudge["rows"]):
        assert [row["steps"] for row in rows] == list(bench.HORIZONS)
    # one frame after the nudge the free-falling cube is still as far off as it was moved
    assert result["physics_nudged_by_1_mm"][0]["translation_rmse_m"] == pytest.approx(1e-3, rel=1e-3)
    assert nudge["rows"][0]["translation_rmse_m"] == pytest.approx(nudge["nudge_m"], rel=1e-3)
    assert result["physics_restarted_from_pose_and_velocity"][0]["translation_rmse_m"] < 1e-6
