"""Statistics shared by the measuring code: medians with quartiles, and Pareto fronts."""

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


def pareto_front(seconds, errors) -> np.ndarray:
    """(n,), (n,) -> (n,) bool: points that no other point beats, i.e. none is at least as fast
    and at least as accurate and strictly better in one. Lower is better on both axes (pass
    −accuracy for a higher-is-better figure); points with a non-finite value are never on it.
    Equal points are all on the front."""
    seconds, errors = np.asarray(seconds, np.float64), np.asarray(errors, np.float64)
    finite = np.isfinite(seconds) & np.isfinite(errors)
    front = np.zeros(len(seconds), bool)
    best_error, best_seconds = np.inf, np.nan
    for i in np.lexsort((errors, seconds)):  # by seconds, ties by error
        if not finite[i]:
            continue
        if errors[i] < best_error or (errors[i] == best_error and seconds[i] == best_seconds):
            front[i] = True
            best_error, best_seconds = min(errors[i], best_error), seconds[i]
    return front
