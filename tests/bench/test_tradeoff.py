import csv
import json
import typing

import numpy as np
import pytest
import trimesh

from fignetctl.bench import tradeoff
from fignetctl.bench.stats import median_iqr, pareto_front


def brute_force_front(seconds, errors):
    """A point is on the front when no other point is <= on both and < on one."""
    n = len(seconds)
    finite = np.isfinite(seconds) & np.isfinite(errors)
    front = np.zeros(n, bool)
    for i in range(n):
        if not finite[i]:
            continue
        beaten = any(
            finite[j]
            and seconds[j] <= seconds[i]
            and errors[j] <= errors[i]
            and (seconds[j] < seconds[i] or errors[j] < errors[i])
            for j in range(n)
        )
        front[i] = not beaten
    return front


@pytest.mark.parametrize("seed", range(40))
def test_pareto_front_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 25))
    seconds = rng.integers(0, 6, n).astype(float)  # small integer grid: many ties and duplicates
    errors = rng.integers(0, 6, n).astype(float)
    if seed % 3 == 0:
        errors[rng.integers(n)] = np.nan
    np.testing.assert_array_equal(pareto_front(seconds, errors), brute_force_front(seconds, errors))


def test_pareto_front_small_cases():
    assert pareto_front([], []).tolist() == []
    assert pareto_front([1.0, 2.0, 3.0], [3.0, 2.0, 1.0]).tolist() == [True, True, True]
    assert pareto_front([1.0, 2.0], [1.0, 2.0]).tolist() == [True, False]
    assert pareto_front([1.0, 1.0], [2.0, 2.0]).tolist() == [True, True]


def point(setting, seconds, error):
    return {
        "setting": setting,
        "seconds": median_iqr(seconds),
        "error": median_iqr(error),
        "extra": median_iqr([7.0]),
    }


def test_higher_is_better_flips_the_accuracy_axis():
    points = [point("a", [1.0], [20.0]), point("b", [2.0], [25.0]), point("c", [3.0], [22.0])]
    result = tradeoff.make_result("nerf-steps", "steps", "s", "PSNR", points, "m", higher_is_better=True)
    assert [p["pareto"] for p in result["points"]] == [True, True, False]


def test_median_iqr_ignores_non_finite_values():
    stat = median_iqr([1.0, 2.0, 3.0, np.nan])
    assert stat == {"median": 2.0, "q25": 1.5, "q75": 2.5, "n": 3}
    assert median_iqr([np.nan])["n"] == 0


def test_write_result_json_csv_and_png(tmp_path):
    points = [
        point(16, [0.1, 0.2, 0.3], [3.0, 4.0]),
        point("full", [1.0, 1.2], [2.0, 2.5]),
        point(64, [0.5], [5.0]),
    ]
    result = tradeoff.make_result("decimation", "faces", "seconds", "error (m)", points, "method", ["a note"])
    paths = [tmp_path / f"t.{ext}" for ext in ("json", "csv", "png")]
    tradeoff.write_result(result, *paths)
    back = json.loads(paths[0].read_text())
    assert back["format"] == tradeoff.FORMAT and [p["pareto"] for p in back["points"]] == [True, True, False]
    rows = list(csv.reader(paths[1].open()))
    assert rows[0][:2] == ["setting", "seconds_median"] and rows[0][-1] == "extra"
    assert (
        rows[1][0] == "16"
        and float(rows[1][1]) == pytest.approx(0.2)
        and rows[1][9] == "1"
        and float(rows[1][-1]) == 7.0
    )
    assert paths[2].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "t.csv",
        "t.json",
        "t.png",
    ]  # no temporary files left


def test_nerf_steps_reads_a_learning_curve(tmp_path):
    curve = {
        "machine": "m",
        "capture": "c",
        "results": [
            {
                "preset": "fast",
                "curve": [
                    {"step": 100, "train_seconds": 10.0, "held_out_psnr": 20.0},
                    {"step": 200, "train_seconds": 20.0, "held_out_psnr": 19.0},
                ],
            }
        ],
    }
    path = tmp_path / "curve.json"
    path.write_text(json.dumps(curve))
    result = tradeoff.sweep_nerf_steps(path, tradeoff.QUICK)
    assert [p["setting"] for p in result["points"]] == ["fast 100", "fast 200"]
    assert [p["pareto"] for p in result["points"]] == [True, False]
    assert result["points"][0]["error"]["n"] == 1


def test_chamfer_fraction_is_zero_for_the_same_mesh_and_grows_with_scale():
    box = trimesh.creation.box()
    assert tradeoff.chamfer_fraction(box, box) < 0.02
    bigger = trimesh.creation.box(extents=(1.2, 1.2, 1.2))
    assert tradeoff.chamfer_fraction(bigger, box) == pytest.approx(0.1, abs=0.03)


def test_marching_cubes_sweep_on_an_analytic_sphere(tmp_path, monkeypatch):
    centre, radius = np.array([0.0, 0.0, 0.5]), 0.2
    truth = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    truth.apply_translation(centre)
    (tmp_path / "ground_truth" / "objects").mkdir(parents=True)
    truth.export(tmp_path / "ground_truth" / "objects" / "ball.obj")
    (tmp_path / "prompts.json").write_text(json.dumps({"objects": [{"id": 1, "name": "ball", "points": []}]}))

    class Sphere:
        metrics: typing.ClassVar[dict] = {}

        @staticmethod
        def density(points):
            solid = (np.linalg.norm(points - centre, axis=1) < radius) | (
                points[:, 2] < 0.25
            )  # a ball over a floor
            return np.where(solid, 1000.0, 0.0)

    import fignetctl.core.nerf.io

    monkeypatch.setattr(fignetctl.core.nerf.io, "load_nerf", lambda path: Sphere())
    result = tradeoff.sweep_marching_cubes(tmp_path, "sphere.pt", tradeoff.QUICK, resolutions=(12, 32))
    coarse, fine = (p["error"]["median"] for p in result["points"])
    assert fine < coarse < 0.1
    assert all(p["seconds"]["n"] == 1 for p in result["points"])
