"""benchmarks/frame_motion.py: the shares it reports, against counting by hand."""

import numpy as np
import pytest

from tests.bench import load_benchmark

frame_motion = load_benchmark("frame_motion")


def test_shares_are_the_fewest_busiest_frames_that_hold_them_and_the_first_frames_share():
    rng = np.random.default_rng(3)
    motions = [rng.exponential(size=n) ** 2 for n in (40, 55, 33)]
    result = frame_motion.motion_shares(motions, energy_shares=(0.5, 0.9), first_frames=10)
    energy = np.concatenate([m**2 for m in motions])
    for share in (0.5, 0.9):
        fewest = next(
            k for k in range(1, len(energy) + 1) if np.sort(energy)[::-1][:k].sum() >= share * energy.sum()
        )
        assert result["fraction_of_frames_holding"][str(share)] == pytest.approx(fewest / len(energy))
    first = sum((m[:10] ** 2).sum() for m in motions)
    assert result["first_10_frames"]["share"] == pytest.approx(first / energy.sum())
    assert result["first_10_frames"]["fraction_of_frames"] == pytest.approx(30 / 128)
    assert result["frames"] == 128
