"""Statistics of the reports (anukf.md eqs 50-52): per-track RMSE, track average, improvement,
bootstrap resampling, paired comparisons, percentile intervals, NEES band words.

Each paper equation is one function here: eq 50 (and 52, the same with ``sse_att``) is
:func:`rmse`, eq 51 :func:`track_average`, the papers' "Imprv." column :func:`improvement`.
Every bootstrap of the reports draws its resamples with :func:`resample_counts`.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.experiments import metrics as eqs
from nespm_cli.reports.markdown import DASH, SIG_MARK, SMALL_MARK
from nespm_cli.reports.thresholds import PRACTICAL_PCT  # the default practical threshold [%] (re-exported)
#: Fewest paired runs per track for which a percentile-bootstrap interval is trusted; below it the
#: interval is marked ``†`` and no significance is claimed.
MIN_PAIRED_RUNS = 10
NEES_DOF = 6
Z95 = 1.959963984540054  # two-sided 95 % normal quantile


# metric key -> (sse column, display name, unit): the columns of the papers' tables
METRICS: dict[str, tuple[str, str, str]] = {
    "vrmse": ("sse_vel", "VRMSE", "m/s"),
    "mrmse": ("sse_att", "MRMSE", "rad"),
}


# every RMS metric pooled as eq 50 (sum of squares over sum of epochs); "hpe" needs HPE_COLUMNS
RMS_METRICS: dict[str, tuple[str, str, str]] = {
    **METRICS,
    "hpe": ("sse_hpe", "RMS horizontal position error", "m"),
}

# metrics averaged over a track's runs, then over tracks (the tables' final HPE); key -> (column, name, unit)
MEAN_METRICS: dict[str, tuple[str, str, str]] = {
    "hpe_final": ("hpe_final", "final horizontal position error", "m"),
}

#: every metric a paired comparison can use
PAIRED_METRICS: dict[str, tuple[str, str, str]] = {**RMS_METRICS, **MEAN_METRICS}


def has_posterior(metrics: pd.DataFrame) -> bool:
    """The folder has the posterior sums (``*_post``, :data:`metrics.POSTERIOR_COLUMNS`) for every row
    whose papers' sum is finite; folders written before them, or grown from such a folder, have not."""
    cols = eqs.POSTERIOR_COLUMNS
    if not all(p in metrics.columns for p in cols.values()):
        return False
    return all(bool((np.isfinite(metrics[p].to_numpy(float)) | ~np.isfinite(metrics[c].to_numpy(float))).all())
               for c, p in cols.items() if c in metrics.columns)


def posterior_view(metrics: pd.DataFrame) -> pd.DataFrame:
    """``metrics`` with the papers' sums (``sse_vel``, ``sse_att``, ``sse_hpe``, ``n_samples``) replaced by
    their posterior twins, the sums over the epochs after t = 0 (the t = 0 rule, docs/report.md), and the
    per-run mean NEES and vertical RMS (``nees``, ``vert_rms``) by theirs (``nees_post``, ``vert_rms_post``,
    :data:`metrics.POSTERIOR_SUMMARIES`) where the folder has them (``attrs["posterior_nees"]``), so
    every function here computes the posterior summaries and improvements from them; ``attrs["posterior"]``
    True. A folder without them (:func:`has_posterior`) comes back with the same numbers (``attrs["posterior"]``
    False): its improvements include the t = 0 error, and the report says so once."""
    if not has_posterior(metrics):
        out = metrics.copy(deep=False)  # the caller's frame keeps its attrs
        out.attrs["posterior"] = out.attrs["posterior_nees"] = False
        return out
    out = metrics.assign(**{c: metrics[p] for c, p in eqs.POSTERIOR_COLUMNS.items() if c in metrics.columns},
                         **{c: metrics[p] for c, p in eqs.POSTERIOR_SUMMARIES.items() if p in metrics.columns})
    out.attrs["posterior"] = True
    out.attrs["posterior_nees"] = "nees_post" in metrics.columns  # False: a folder written before that twin
    return out


def rmse(sse: Any, n: Any, counts: np.ndarray | None = None) -> Any:
    """Eq 50 (and eq 52 with ``sse_att``): ``sqrt(sum(sse) / sum(n_samples))`` over a set of runs.

    Without ``counts``: one float (:func:`nespm_cli.experiments.metrics.rmse`; NaN for no run).
    With ``counts`` of shape ``(n_boot, n_runs)`` (:func:`resample_counts`): the run sums are
    weighted by each resample's multiplicities, one value per resample."""
    sse = np.asarray(sse, dtype=float)
    n = np.asarray(n, dtype=float)
    if counts is None:
        return eqs.rmse(sse, n) if sse.size else math.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sqrt((counts @ sse) / (counts @ n))


def track_average(per_track: Any) -> Any:
    """Eq 51: ``sqrt(mean over tracks of RMSE_track**2)`` (NaN if any is NaN, or no track).

    ``per_track`` is 1-D (one value per track: a float) or a list of per-track arrays
    (e.g. bootstrap replicates: one value per replicate)."""
    x = np.asarray(per_track, dtype=float)
    if not x.size:
        return math.nan
    out = np.sqrt(np.mean(x**2, axis=0))
    return float(out) if out.ndim == 0 else out


def track_value(runs: pd.DataFrame, key: str, counts: np.ndarray | None = None) -> Any:
    """One track's value of metric ``key`` over ``runs`` (rows of one filter): eq 50 of its error
    sums for an RMS metric (:data:`RMS_METRICS`), the mean over the runs for a mean metric
    (:data:`MEAN_METRICS`). With ``counts`` (n_boot, n_runs): one value per resample."""
    if key in MEAN_METRICS:
        x = runs[MEAN_METRICS[key][0]].to_numpy(float)
        if counts is None:
            return float(np.mean(x)) if x.size else math.nan
        with np.errstate(divide="ignore", invalid="ignore"):
            return (counts @ x) / counts.sum(axis=1)
    return rmse(runs[RMS_METRICS[key][0]], runs["n_samples"], counts)


def over_tracks(per_track: Any, key: str) -> Any:
    """Metric ``key`` over tracks: eq 51 (:func:`track_average`) for an RMS metric, the plain mean
    for a mean metric; ``per_track`` as in :func:`track_average`."""
    if key in MEAN_METRICS:
        x = np.asarray(per_track, dtype=float)
        if not x.size:
            return math.nan
        out = np.mean(x, axis=0)
        return float(out) if out.ndim == 0 else out
    return track_average(per_track)


def improvement(value: float | np.ndarray, ref: float | np.ndarray) -> float | np.ndarray:
    """Papers' improvement of the reference over a row, percent: 100 * (value - ref) / value."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return 100.0 * (np.asarray(value) - np.asarray(ref)) / np.asarray(value)


def resample_counts(n_runs: int, n_boot: int, rng: np.random.Generator) -> np.ndarray:
    """(n_boot, n_runs) multiplicities of each run in each with-replacement resample."""
    idx = rng.integers(0, n_runs, size=(n_boot, n_runs))
    flat = idx + (np.arange(n_boot, dtype=np.int64) * n_runs)[:, None]
    return np.bincount(flat.ravel(), minlength=n_boot * n_runs).reshape(n_boot, n_runs).astype(float)


def track_rng(seed: int, track: Any) -> np.random.Generator:
    """The random stream of one track's resamples: it depends only on ``(seed, track)``."""
    return np.random.default_rng([int(seed), int(track)])


def lost_by_any(metrics: pd.DataFrame) -> pd.Series:
    """(rows,) bool: the row's run (same ``track`` and ``run``, and ``value`` in a sweep) was lost
    (``diverged``) by this or some other filter of ``metrics``. The per-filter tables leave these runs out for
    every filter, so each filter is judged on the same runs and none looks better for losing
    one; each filter's own loss count stands beside (docs/filters.md, "Lost and inconsistent
    runs"). A filter that lost every run of a track (of a swept value) is left out of this rule
    there: its numbers are undefined anyway, and the others keep theirs."""
    group = [k for k in ("value", "track") if k in metrics.columns]
    lost = metrics["diverged"].astype(bool)
    all_lost = lost.groupby([metrics[k] for k in group + ["filter"]], sort=False).transform("all")
    counted = lost & ~all_lost
    return counted.groupby([metrics[k] for k in group + ["run"]], sort=False).transform("any").astype(bool) | lost


def paired_runs(metrics: pd.DataFrame, track: Any, a: str, b: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Rows of filters ``a`` and ``b`` on ``track`` for the runs diverged in neither, aligned by run
    (indexed by ``run``, ascending). Row positions are found in NumPy: the report asks for a pair ~100 times."""
    on_track = metrics["track"].to_numpy() == track
    name = metrics["filter"].to_numpy()
    ia, ib = np.flatnonzero(on_track & (name == a)), np.flatnonzero(on_track & (name == b))
    run = metrics["run"].to_numpy()
    _, pa, pb = np.intersect1d(run[ia], run[ib], assume_unique=True, return_indices=True)
    lost = metrics["diverged"].to_numpy(bool)
    keep = ~(lost[ia[pa]] | lost[ib[pb]])
    return metrics.iloc[ia[pa][keep]].set_index("run"), metrics.iloc[ib[pb][keep]].set_index("run")


def metric_keys(metrics: pd.DataFrame, keys: Sequence[str] | None) -> list[str]:
    """The metric keys asked for (default VRMSE, MRMSE), checked against :data:`PAIRED_METRICS`."""
    keys = list(METRICS) if keys is None else list(keys)
    unknown = [k for k in keys if k not in PAIRED_METRICS]
    if unknown:
        raise ValueError(f"unknown metric key(s) {unknown}; known: {list(PAIRED_METRICS)}")
    return keys


def shared_tracks(metrics: pd.DataFrame, a: str, b: str) -> list:
    return sorted(set(metrics.loc[metrics["filter"] == a, "track"])
                  & set(metrics.loc[metrics["filter"] == b, "track"]))


def paired_run_counts(metrics: pd.DataFrame, a: str, b: str) -> dict[Any, int]:
    """Per shared track: the number of runs that diverged in neither ``a`` nor ``b`` (the pairs)."""
    return {track: len(paired_runs(metrics, track, a, b)[0]) for track in shared_tracks(metrics, a, b)}


def paired_bootstrap(
    metrics: pd.DataFrame, row: str, ref: str, n_boot: int = 2000, seed: int = 0,
    keys: Sequence[str] | None = None,
) -> dict[str, np.ndarray]:
    """Bootstrap replicates of the improvement of ``ref`` over ``row`` for VRMSE and MRMSE.

    Per track, run indices (of the runs diverged in neither filter) are resampled with
    replacement; both filters use the same resample (paired). Each replicate recomputes
    eq 50/52 per track from the resampled error sums and the track average (eq 51) of
    both filters, then the improvement. The resamples of a track depend only on
    ``(seed, track)`` and the number of paired runs (not on ``keys``). Returns ``{"vrmse":
    (n_boot,), "mrmse": (n_boot,)}`` (or the ``keys`` asked for, e.g. ``"hpe"`` for the RMS
    horizontal position error, ``"hpe_final"`` for the mean final one, :func:`track_value`); all NaN
    if some shared track has no paired run.
    """
    keys = metric_keys(metrics, keys)
    tracks = shared_tracks(metrics, row, ref)
    nan = {k: np.full(n_boot, np.nan) for k in keys}
    if not tracks or n_boot < 1:
        return nan
    ms: dict[str, dict[str, list[np.ndarray]]] = {k: {"row": [], "ref": []} for k in keys}
    for track in tracks:
        A, B = paired_runs(metrics, track, row, ref)
        if len(A) == 0:
            return nan
        counts = resample_counts(len(A), n_boot, track_rng(seed, track))
        for key in keys:
            for side, T in (("row", A), ("ref", B)):
                ms[key][side].append(track_value(T, key, counts))
    return {key: improvement(over_tracks(ms[key]["row"], key), over_tracks(ms[key]["ref"], key)) for key in keys}


def paired_averages(
    metrics: pd.DataFrame, a: str, b: str, keys: Sequence[str] | None = None
) -> dict[str, tuple[float, float]]:
    """Track averages (eq 51) of ``a`` and ``b`` over the runs diverged in neither: ``{key: (m_a, m_b)}``
    (NaN when some shared track has no such run, or no track is shared)."""
    keys = metric_keys(metrics, keys)
    tracks = shared_tracks(metrics, a, b)
    pairs = [paired_runs(metrics, track, a, b) for track in tracks]
    out = {}
    for key in keys:
        ms: dict[str, list[float]] = {"a": [], "b": []}
        for A, B in pairs:
            for side, T in (("a", A), ("b", B)):
                ms[side].append(track_value(T, key))
        out[key] = (over_tracks(ms["a"], key), over_tracks(ms["b"], key)) if tracks else (math.nan, math.nan)
    return out


def paired_improvement(
    metrics: pd.DataFrame, row: str, ref: str, keys: Sequence[str] | None = None
) -> dict[str, float]:
    """Improvement of ``ref`` over ``row`` (percent) for VRMSE and MRMSE (or ``keys``), on the
    runs that diverged in neither filter: the point estimate that :func:`paired_bootstrap`'s
    interval belongs to (with no divergence it equals the improvement of the two track averages)."""
    out = {}
    for key, (m_row, m_ref) in paired_averages(metrics, row, ref, keys).items():
        with np.errstate(all="ignore"):
            out[key] = float(improvement(m_row, m_ref))
    return out


def ci_marks(lo: float, hi: float, pairs_min: int, min_pairs: int = MIN_PAIRED_RUNS) -> tuple[bool, bool, str]:
    """``(excludes_0, significant, mark)`` of an improvement interval: significant when the interval
    excludes 0 and every track has at least ``min_pairs`` paired runs; mark ``*`` if significant,
    ``†`` if the sample is too small for the percentile bootstrap, else ``""``."""
    excludes = bool(np.isfinite(lo) and np.isfinite(hi) and (lo > 0 or hi < 0))
    small = pairs_min < min_pairs
    significant = excludes and not small
    return excludes, significant, interval_mark(significant, pairs_min, min_pairs)


def interval_mark(significant: bool, pairs_min: int, min_pairs: int = MIN_PAIRED_RUNS) -> str:
    """The mark of an improvement interval: ``†`` from fewer than ``min_pairs`` paired runs on some
    track (whatever the interval), else ``*`` when significant, else ``""``."""
    return SMALL_MARK if pairs_min < min_pairs else SIG_MARK if significant else ""


def percentile_ci(reps: np.ndarray, axis: int | None = None) -> tuple[Any, Any]:
    """95 % percentile interval (2.5 / 97.5 %) of bootstrap replicates, NaN unless every
    replicate is finite. With ``axis``: one interval per column (arrays ``lo``, ``hi``)."""
    reps = np.asarray(reps, dtype=float)
    if axis is not None:
        lo, hi = np.percentile(reps, [2.5, 97.5], axis=axis)
        bad = ~np.all(np.isfinite(reps), axis=axis)
        return np.where(bad, np.nan, lo), np.where(bad, np.nan, hi)
    if reps.size and np.all(np.isfinite(reps)):
        lo, hi = np.percentile(reps, [2.5, 97.5])
        return float(lo), float(hi)
    return math.nan, math.nan


def nees_check(mean: float, n: int) -> tuple[float, float, str]:
    """``(lo, hi, word)``: the 95 % band of a mean NEES over ``n`` runs and the consistency word
    (``consistent``, ``overconfident``, ``conservative``; ``—`` without a finite NEES)."""
    if not (n > 0 and np.isfinite(mean)):
        return math.nan, math.nan, DASH
    lo, hi = eqs.nees_band(NEES_DOF, int(n))
    word = "overconfident" if mean > hi else "conservative" if mean < lo else "consistent"
    return lo, hi, word


def wilson_interval(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion ``k / n`` (NaN, NaN when n == 0)."""
    if n <= 0:
        return math.nan, math.nan
    p = k / n
    den = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    lo, hi = max(0.0, centre - half), min(1.0, centre + half)
    if k == 0:
        lo = 0.0
    if k == n:
        hi = 1.0
    return lo, hi


def check_practical_pct(practical_pct: float) -> None:
    """Raise NespmError unless ``practical_pct`` is a finite percentage >= 0."""
    if not (np.isfinite(practical_pct) and practical_pct >= 0):
        raise NespmError(f"--practical must be a percentage >= 0, got {practical_pct}")
