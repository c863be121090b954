"""benchmarks/paired_loss.py: step-by-step differences of two runs' losses, in windows."""

import math

import pytest

from tests.bench import load_benchmark

paired_loss = load_benchmark("paired_loss")


def test_windows_hold_both_means_and_the_paired_difference_with_its_standard_error(tmp_path):
    first = {step: 1.0 + 0.1 * (step % 3) for step in range(1, 9)}  # what both runs drew
    second = {step: loss - 0.05 * (step > 4) - 0.01 * (step % 2) for step, loss in first.items()}
    rows = paired_loss.paired_windows(first, second, window=4)
    assert [row["steps"] for row in rows] == [[1, 4], [5, 8]]
    assert rows[0]["first_mean"] == pytest.approx(sum(first[s] for s in range(1, 5)) / 4)
    assert rows[0]["difference"] == pytest.approx(-0.005)
    assert rows[1]["difference"] == pytest.approx(-0.055)
    # differences of ±0.005 about their mean: standard deviation 0.005·√(4/3), over √4
    assert rows[1]["standard_error"] == pytest.approx(0.005 * math.sqrt(4 / 3) / 2)
    path = tmp_path / "loss.csv"
    path.write_text("step,loss,seconds\n1,0.5,1.0\n2,0.25,2.0\n")
    assert paired_loss.losses(path) == {1: 0.5, 2: 0.25}


def test_only_the_steps_both_runs_logged_are_compared():
    rows = paired_loss.paired_windows({1: 1.0, 2: 1.0, 3: 1.0}, {2: 0.5, 3: 0.7, 9: 0.0}, window=10)
    assert len(rows) == 1 and rows[0]["steps"] == [2, 3]
    assert rows[0]["difference"] == pytest.approx(-0.4)
