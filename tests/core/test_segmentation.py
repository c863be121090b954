"""fill_holes: every hole, or only the small ones."""

import numpy as np

from fignetctl.core.segmentation import fill_holes


def test_fill_holes_keeps_openings_larger_than_the_limit():
    mask = np.zeros((60, 60), bool)
    mask[10:50, 10:50] = True
    mask[20:30, 20:30] = False  # an opening: 100 of 1500 pixels
    mask[40, 40] = False  # a speck
    filled = fill_holes(mask)
    assert filled[10:50, 10:50].all()
    some = fill_holes(mask, max_fraction=0.02)
    assert some[40, 40] and not some[20:30, 20:30].any()
    assert (some & ~mask).sum() == 1
    assert not fill_holes(np.zeros((5, 5), bool), max_fraction=0.02).any()
