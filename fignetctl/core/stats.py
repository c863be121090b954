"""Summary statistics shared by the measuring code."""

from __future__ import annotations

import numpy as np


def median_iqr(values) -> dict:
    """Finite values -> median, quartiles and n (NaN figures and n=0 when none is finite)."""
    values = np.asarray(values, np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return {"median": float("nan"), "q25": float("nan"), "q75": float("nan"), "n": 0}
    q25, median, q75 = np.percentile(values, [25, 50, 75])
    return {"median": float(median), "q25": float(q25), "q75": float(q75), "n": int(values.size)}
