"""The model-against-baseline comparison of `evaluate` (evaluation.compare), checked against
direct computation."""

import numpy as np
import pytest

from fignetctl.core.model.evaluation import compare, summarize_errors


def records(rng, sizes, scale=1.0):
    return [{"translation": scale * rng.uniform(0, 3, n), "rotation": rng.uniform(0, 180, n)} for n in sizes]


def test_point_estimates_equal_the_pooled_metrics():
    rng = np.random.default_rng(0)
    model, baseline = records(rng, [3, 7, 1, 5]), records(rng, [3, 7, 1, 5])
    result = compare(model, baseline)
    m, b = summarize_errors(model), summarize_errors(baseline)
    assert result["translation_rmse_ratio"] == pytest.approx(
        m["translation_rmse_m"] / b["translation_rmse_m"]
    )
    assert result["rotation_error_difference_deg"] == pytest.approx(
        m["rotation_error_deg"] - b["rotation_error_deg"]
    )
    closer = np.concatenate([x["translation"] < y["translation"] for x, y in zip(model, baseline)]).mean()
    assert result["objects_closer"] == pytest.approx(closer)
    assert result["objects"] == 16 and result["trajectories"] == 4
    low, high = result["translation_rmse_ratio_95"]
    assert low <= result["translation_rmse_ratio"] <= high


def test_bootstrap_interval_matches_a_resampling_loop():
    rng = np.random.default_rng(1)
    model, baseline = records(rng, [4, 2, 6, 3, 5]), records(rng, [4, 2, 6, 3, 5])
    result = compare(model, baseline, resamples=300, seed=7)
    picks = np.random.default_rng(7).integers(0, 5, size=(300, 5))
    ratios, differences = [], []
    for pick in picks:  # resample whole trajectories, pool their objects, recompute both metrics
        m, b = summarize_errors([model[i] for i in pick]), summarize_errors([baseline[i] for i in pick])
        ratios.append(m["translation_rmse_m"] / b["translation_rmse_m"])
        differences.append(m["rotation_error_deg"] - b["rotation_error_deg"])
    np.testing.assert_allclose(result["translation_rmse_ratio_95"], np.percentile(ratios, [2.5, 97.5]))
    np.testing.assert_allclose(
        result["rotation_error_difference_deg_95"], np.percentile(differences, [2.5, 97.5])
    )


def test_a_model_at_half_the_error_everywhere_has_a_tight_interval_at_one_half():
    rng = np.random.default_rng(2)
    baseline = records(rng, [5, 5, 5])
    model = [{"translation": 0.5 * r["translation"], "rotation": r["rotation"] - 10} for r in baseline]
    result = compare(model, baseline)
    assert result["translation_rmse_ratio_95"] == pytest.approx([0.5, 0.5])
    assert result["rotation_error_difference_deg_95"] == pytest.approx([-10, -10])
    assert result["objects_closer"] == 1.0


def test_identical_methods_tie():
    rng = np.random.default_rng(3)
    same = records(rng, [2, 8])
    result = compare(same, same)
    assert result["translation_rmse_ratio"] == 1.0 and result["translation_rmse_ratio_95"] == [1.0, 1.0]
    assert result["objects_closer"] == 0.0


def test_unpaired_records_are_refused():
    rng = np.random.default_rng(4)
    with pytest.raises(ValueError, match="same trajectories"):
        compare(records(rng, [2, 3]), records(rng, [2]))
