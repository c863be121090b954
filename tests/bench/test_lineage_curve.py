"""benchmarks/lineage_curve.py: the power law it fits, the samples it reads off, and the stages it
reads from the stored results."""

import json
import sys

import numpy as np
import pytest

from tests.bench import load_benchmark

lineage_curve = load_benchmark("lineage_curve")


def test_the_power_law_is_recovered_and_read_off_at_a_target():
    samples = np.array([1e5, 2e5, 4e5, 8e5])
    law = lineage_curve.power_law(samples, 3.0 * samples**-0.2)
    assert law == pytest.approx((3.0, -0.2))
    reach = lineage_curve.samples_for(0.25, law)
    assert 3.0 * reach**-0.2 == pytest.approx(0.25)
    assert lineage_curve.samples_for(0.25, (3.0, 0.1)) is None  # an error that grows never gets there


def test_a_stage_is_read_from_its_measures():
    stage = {"run": "velocity-continued-gpu-400-steps", "steps": 400, "examples_per_step": 128, "runs": 1}
    figures = lineage_curve.stage_figures(stage)
    evaluation = json.loads((lineage_curve.RESULTS / stage["run"] / "eval.json").read_text())
    model = evaluation["metrics"]["model"]
    assert figures["samples_added"] == 51_200
    assert figures["10_steps_m"] == model["0.33_seconds"]["all"]["translation_rmse_m"]
    assert figures["50_steps_m"] == model["50_steps"]["all"]["translation_rmse_m"]
    assert 0 < figures["impact_angular_captured"] < figures["impact_linear_captured"] < 1


def test_the_stored_lineage_sums_its_samples_and_plots(tmp_path, monkeypatch):
    output, image = tmp_path / "curve.json", tmp_path / "curve.png"
    monkeypatch.setattr(sys, "argv", ["lineage_curve.py", "-o", str(output), "--plot", str(image)])
    lineage_curve.main()
    result = json.loads(output.read_text())
    stages = result["stages"]
    assert [s["samples"] for s in stages] == list(np.cumsum([s["samples_added"] for s in stages]))
    assert stages[-1]["samples"] == 951_028
    assert result["fits"]["10_steps_m"]["law"][1] < 0 and image.stat().st_size > 10_000
