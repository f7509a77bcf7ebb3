"""
The statistics of the results pages: rliable's probability of improvement P(X > Y) with a stratified-bootstrap interval
(:data:`RESAMPLES` resamples drawn from NumPy seed :data:`BOOTSTRAP_SEED`: exactly the resamples rliable's
``get_interval_estimates`` draws from that seed, in one vectorised step), the one-sided Mann–Whitney p beside it, and
what P reads without the better arm's best seeds (:data:`WITHOUT_BEST`).
"""

from typing import Any

import numpy as np
from scipy import stats


#: bootstrap resamples of every P(X > Y) interval: the evidence protocol's number
RESAMPLES = 50_000
#: the NumPy seed each comparison's resamples are drawn from (one pair's interval depends on that pair's runs only)
BOOTSTRAP_SEED = 0
#: the interval's coverage
CONFIDENCE = 0.95
#: a comparison is also read with the better arm's best 1 and 2 seeds left out: a claim must not hinge on them
WITHOUT_BEST = (1, 2)


def spread(values: np.ndarray | None) -> dict[str, Any] | None:
    """Mean, std and per-seed values of a row's returns (``None`` for a row without runs), rounded for the page."""
    if values is None:
        return None
    return {
        "mean": round(float(values.mean()), 4),
        "std": round(float(values.std()), 4),
        "per_seed": [round(float(value), 3) for value in values],
    }


def bootstrap_improvement(x: np.ndarray, y: np.ndarray, reps: int, seed: int) -> tuple[float, list[float]]:
    """
    rliable's probability of improvement P(X > Y) and its stratified-bootstrap percentile interval, exactly as
    ``rliable.library.get_interval_estimates({k: [x[:, None], y[:, None]]}, metrics.probability_of_improvement,
    reps=reps)`` gives them after ``np.random.seed(seed)``, without its loop of one Mann–Whitney test per resample
    (about 30 s of CPU a pair at 50,000 resamples: two hours for the page with its best-seed readings).

    rliable's ``StratifiedIndependentBootstrap`` draws, per resample, ``np.random.choice(len(x), (len(x), 1))`` then the
    same for ``y`` from NumPy's legacy global generator: a legacy ``randint`` with an array of bounds draws the same
    numbers in the same order, so one call draws every resample. P of a resample is the Mann–Whitney U of X over Y
    divided by ``len(x) * len(y)`` (ties count one half), as rliable's ``probability_of_improvement`` computes it;
    the interval is arch's percentile interval. ``tests/test_benchmarks.py`` checks the equality with rliable.
    """
    n_x, n_y = len(x), len(y)
    bounds = np.tile(np.r_[np.full(n_x, n_x), np.full(n_y, n_y)], reps)
    draws = np.random.RandomState(seed).randint(0, bounds).reshape(reps, n_x + n_y)
    resampled_x, resampled_y = x[draws[:, :n_x]], y[draws[:, n_x:]]

    def improvement_of(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """U / (n_x n_y) of each row of a over the same row of b."""
        a, b = a[..., :, None], b[..., None, :]
        return ((a > b).sum(axis=(-2, -1)) + 0.5 * (a == b).sum(axis=(-2, -1))) / (n_x * n_y)

    results = improvement_of(resampled_x, resampled_y)
    alpha = (1.0 - CONFIDENCE) / 2
    low, high = np.percentile(results, [100 * alpha, 100 * (1.0 - alpha)])
    return float(improvement_of(x, y)), [float(low), float(high)]


def mann_whitney_p(x: np.ndarray, y: np.ndarray) -> float:
    """The one-sided Mann–Whitney U test's p of X > Y (scipy's default method: exact for small samples without ties)."""
    return float(stats.mannwhitneyu(x, y, alternative="greater").pvalue)


def rounded(x: np.ndarray, y: np.ndarray, p: float, interval: list[float]) -> dict[str, Any]:
    """A comparison's entry as ``results.json`` keeps it: P and its interval to four decimals, the Mann–Whitney p beside
    them, the seeds of each side."""
    return {
        "p": round(p, 4),
        "ci95": [round(bound, 4) for bound in interval],
        "mann_whitney_p": float(f"{mann_whitney_p(x, y):.4g}"),
        "seeds": [len(x), len(y)],
    }


def improvement(
    x: np.ndarray, y: np.ndarray, seeds_x: list[int] | None = None, reps: int = RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> dict[str, Any]:
    """
    One comparison of X's primary returns with Y's: rliable's P(X > Y) with its 95% stratified-bootstrap interval
    (:func:`bootstrap_improvement`), the one-sided Mann–Whitney p of X > Y beside it, the seeds of each side, and
    ``without_best``: the same read again with X's best 1 and 2 runs (by the primary return) left out, naming their
    seeds (``seeds_x``, X's seeds in the order of ``x``), while X keeps a run. A claim that X is better must still
    read so without them.
    """
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    entry = rounded(x, y, *bootstrap_improvement(x, y, reps, seed))
    if seeds_x is None:
        return entry
    best_first = np.argsort(-x, kind="stable")
    entry["without_best"] = []
    for left_out in WITHOUT_BEST:
        if left_out >= len(x):
            continue
        keep = np.sort(best_first[left_out:])
        reduced = improvement(x[keep], y, reps=reps, seed=seed)
        entry["without_best"].append({"left_out": [seeds_x[i] for i in best_first[:left_out]], **reduced})
    return entry
