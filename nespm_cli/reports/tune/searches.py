"""The held-out numbers of a ``nespm tune`` folder by ``nespm report``'s rules, and its searches compared.

* **The metric** (:func:`accuracy_key`): the objective's own error, the horizontal RMS position error
  where the layout holds position (``--state 15``), else the velocity RMSE; both by the mc report's
  rule (:func:`filter_values`): the posterior sums (the epochs after t = 0,
  :func:`nespm_cli.reports.stats.posterior_view`, docs/report.md "The t = 0 rule"), eq 50 per track
  over the runs no filter of the folder lost, eq 51 over tracks. With ``--objective consistency`` the
  objective's own score is also recomputed held out from the per-epoch ANEES / ANIS
  (:func:`consistency_scores`, :func:`nespm_cli.tuning.objective.consistency`: the same rule).
* **Convergence** (:func:`convergence_of`, :func:`convergence_text`): ``tune.json``'s verdict per filter
  (and per search), or for a folder written before it the same verdict
  (:func:`nespm_cli.tuning.refine.verdict`) from its recorded profile and cross-check.
* **The searches** (``--repeats K``, :func:`searches_section`): each filter's held-out error per search
  (folders :func:`nespm_cli.tuning.heldout.tuned_dir`), their spread, and each tuned filter against the
  most accurate one over the runs *and* the searches: a two-level bootstrap (:func:`compare_searches`), each replicate
  resampling every filter's searches (with replacement) and, per track, the runs (the same runs for
  every search: paired); the point is the mean over searches of each search's error. The comparison
  is **not resolved by the search** when the point improvement of one filter's search over the
  other's changes sign between pairs of searches (every search of A against every search of B, on
  the same runs): the searches' spread alone covers zero.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.experiments.metrics import STAT_BLOCKS
from nespm_cli.nav.state import parse_layout
from nespm_cli.reports.cases import realization_difference
from nespm_cli.reports.markdown import fmt, fmt_imprv, fmt_pct, md_table
from nespm_cli.reports.results import load_results, sensor_dims
from nespm_cli.reports.stats import (ci_marks, improvement, lost_by_any, over_tracks, percentile_ci, posterior_view,
                                     resample_counts, track_rng, track_value)
from nespm_cli.tuning.flat import training_score
from nespm_cli.tuning.heldout import tuned_dir
from nespm_cli.tuning.objective import consistency
from nespm_cli.tuning.refine import TOLERANCE, verdict

#: metric key (reports.stats.RMS_METRICS) -> (name, unit) of the held-out error
ACCURACY = {"vrmse": ("VRMSE", "m/s"), "hpe": ("RMS horizontal error", "m")}
SEARCH_STREAM = 0x73656172  # "sear": the searches' resamples, apart from the runs' (track_rng)


def accuracy_key(record: dict) -> str:
    """``hpe`` (the horizontal RMS position error) where the tuning's layout holds position, else
    ``vrmse``: the error the objectives ``rmse`` and ``rmse-consistent`` score."""
    state = ((record.get("spec") or {}).get("filter_config") or {}).get("state", "12")
    return "hpe" if parse_layout(state).has("pos") else "vrmse"


def filter_values(metrics: pd.DataFrame, key: str) -> dict[str, float]:
    """``{filter: value}`` of the RMS metric ``key`` (``vrmse``, ``hpe``) by the mc report's rule: the
    posterior sums (t = 0 out; the papers' sums in a folder without them), eq 50 per track over the runs
    no filter of ``metrics`` lost (:func:`stats.lost_by_any`), eq 51 over tracks."""
    m = posterior_view(metrics)
    kept = m[~lost_by_any(m)]
    return {str(f): float(over_tracks([track_value(g, key) for _, g in d.groupby("track", sort=True)], key))
            for f, d in kept.groupby("filter", sort=False)}


def consistency_scores(epochs: pd.DataFrame | None, manifest: dict) -> dict[str, float]:
    """``{filter: score}``: the ``consistency`` objective's score (:func:`nespm_cli.tuning.objective.consistency`:
    the mean over blocks and sensors of ``log(ANEES/3)²``, ``log(ANIS/m)²`` over the epochs after t = 0)
    from the per-epoch averages of an mc folder (every track's epochs pooled); {} without them."""
    if epochs is None or "epoch" not in epochs.columns:
        return {}
    ep = epochs[epochs["epoch"] > 0]
    sensors = [c[4:-5] for c in ep.columns if c.startswith("nis_") and c.endswith("_mean")]
    dims = {s: m for s, m in sensor_dims(manifest, sensors).items() if m}
    out = {}
    for f, d in ep.groupby("filter", sort=False):
        d = d.sort_values(["track", "epoch"])
        cols = {b: d[f"nees_{b}_mean"].to_numpy(float) for b in STAT_BLOCKS if f"nees_{b}_mean" in d.columns}
        nis = {s: d[f"nis_{s}_mean"].to_numpy(float) for s in dims}
        out[str(f)] = consistency({"anees": {b: v for b, v in cols.items() if np.isfinite(v).any()},
                                   "anis": {s: v for s, v in nis.items() if np.isfinite(v).any()}, "dims": dims})
    return out


def convergence_of(entry: dict) -> dict:
    """A search's convergence verdict (``{"status", "short_by", "by", "refine_trials", "start",
    "tolerance"}``): ``entry["convergence"]`` as ``nespm tune`` wrote it, else (a folder written before
    it) :func:`nespm_cli.tuning.refine.verdict` of its recorded profile and cross-check (no refinement)."""
    if entry.get("convergence"):
        return entry["convergence"]
    return verdict(float(entry["score"]), entry.get("profile"), entry.get("cross"), None)


def resolution(entry: dict) -> float:
    """How close to its optimum one filter's search is known to be (relative, on the training score): the
    verdict's tolerance (a converged search: no check step better by more), or the gain it stopped short by
    where that is larger (:func:`convergence_of`)."""
    c = convergence_of(entry)
    return max(float(c.get("tolerance", TOLERANCE) or TOLERANCE), float(c.get("short_by", 0.0) or 0.0))


def search_tie(record: dict, f: str, g: str) -> str:
    """With one search per filter, whether the searches can rank tuned filters ``f`` and ``g`` at all: ``""``
    where their training scores (:func:`training_score`, the same objective on the same runs) differ by more
    than either search's :func:`resolution`, else the words "not resolved by the search" with both figures.
    Why: a converged search only says that no step of its stated sizes beats its end by more than the
    tolerance, so two filters whose training scores lie within it are equally good to the searches, and
    which of them ends ahead held out is where each search stopped: measured on make tune-main's setup, 5
    search seeds, the EKF and UKF-NESPM 0.0-0.13 % apart in training and the held-out order flipping with
    the seed by up to 0.62 % (docs/tuning.md)."""
    best = record.get("best") or {}
    if f not in best or g not in best:
        return ""
    a, b = training_score(best[f]), training_score(best[g])
    gap = abs(a - b) / max(min(abs(a), abs(b)), 1e-300)
    res = max(resolution(best[f]), resolution(best[g]))
    if not gap <= res:
        return ""
    return (f"not resolved by the search: training scores {fmt_pct(100 * gap)} apart, within the searches' "
            f"{fmt_pct(100 * res)} resolution")


def convergence_word(c: dict) -> str:
    """The verdict in a few words (``nespm tune``'s closing line per filter): ``converged``, ``stopped
    short by 3.1 % (profile r_scale_dvl /3)``, ``stopped short (the refinement budget (171 trials) ran
    out)`` when no check found a gain above the tolerance, ``convergence not checked``, or ``""``."""
    status = c.get("status")
    if status == "converged":
        return "converged"
    if status == "stopped short":
        return f"{stopped_short(c)} ({c['by']})" if c.get("by") else stopped_short(c)
    return "convergence not checked" if status == "not checked" else ""


def stopped_short(c: dict) -> str:
    """``stopped short by 3.1 %`` where the verdict's gap exceeds its tolerance, else ``stopped short`` (the
    refinement budget ran out with every check below it)."""
    gap = float(c.get("short_by", 0.0))
    return f"stopped short by {fmt_pct(100 * gap)}" if gap > float(c.get("tolerance", 0.0)) else "stopped short"


def convergence_text(c: dict) -> str:
    """``converged``, ``stopped short by 3.1 % (profile r_scale_dvl /3)`` or ``not checked``, with the
    tolerance and where the refinement started."""
    tol = f"tolerance {100 * float(c.get('tolerance', math.nan)):.1f} %"
    start = c.get("start") or "own"
    refined = (f"; refined {c['refine_trials']} trials from {'its own values' if start == 'own' else start}"
               if c.get("refine_trials") else "")
    if c.get("status") == "converged":
        return f"converged ({tol}{refined})"
    if c.get("status") == "stopped short":
        by = f"{c['by']}; " if c.get("by") else ""
        return f"{stopped_short(c)} ({by}{tol}{refined})"
    return "not checked (no profile, cross-check or refinement: --no-profile)"


def load_searches(out_dir: Path, record: dict) -> list[tuple[int, pd.DataFrame, pd.DataFrame | None, dict]]:
    """``[(k, metrics, epochs, manifest)]`` of the held-out tuned folders of searches 0 .. K-1 that exist
    (``record["repeats"]``, 1 when absent); one line naming a folder whose realizations differ from
    search 0's (:func:`nespm_cli.reports.cases.realization_difference`: they would not pair by run)."""
    out = []
    for k in range(int(record.get("repeats", 1) or 1)):
        folder = Path(out_dir) / tuned_dir(k, record)
        if (folder / "metrics.parquet").is_file():
            out.append((k, *load_results(folder)))
            diff = realization_difference(out[0][3], out[-1][3])
            if diff is not None:
                raise NespmError(f"{folder}: not the realizations of {Path(out_dir) / tuned_dir(out[0][0], record)} "
                                 f"(they differ in {diff}): the searches compare run by run only on the same runs")
    return out


def search_errors(frames: dict[str, list[pd.DataFrame]], key: str, n_boot: int,
                  seed: int = 0) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], int]:
    """``({filter: (point (K,), replicates (K, n_boot))}, pairs_min)``: each search's error ``key`` (eq 50
    per track of the posterior sums, eq 51 over tracks) over the runs no search of any filter of ``frames``
    (``{filter: [metrics of each search]}``) lost, and its bootstrap replicates: per track the runs are
    resampled with replacement (:func:`stats.resample_counts`, stream :func:`stats.track_rng`), the same
    resample for every filter and search (paired); ``pairs_min`` the fewest such runs on a track."""
    parts = [fr[fr["filter"] == f].assign(filter=f"{f}#{k}") for f, fs in frames.items() for k, fr in enumerate(fs)]
    m = posterior_view(pd.concat(parts, ignore_index=True))
    kept = m[~lost_by_any(m)]
    names = {f: [f"{f}#{k}" for k in range(len(fs))] for f, fs in frames.items()}
    points: dict[str, list] = {n: [] for ns in names.values() for n in ns}
    reps: dict[str, list] = {n: [] for n in points}
    pairs_min = 0 if kept.empty else None
    for track, d in kept.groupby("track", sort=True):
        by = {n: g.set_index("run") for n, g in d.groupby("filter", sort=False)}
        runs = sorted(set.intersection(*(set(by[n].index) for n in points))) if set(points) <= set(by) else []
        counts = resample_counts(len(runs), n_boot, track_rng(seed, track)) if runs else None
        pairs_min = len(runs) if pairs_min is None else min(pairs_min, len(runs))
        for n in points:
            points[n].append(track_value(by[n].loc[runs], key) if runs else math.nan)
            reps[n].append(track_value(by[n].loc[runs], key, counts) if runs else np.full(n_boot, np.nan))
    return {f: (np.array([over_tracks(points[n], key) for n in ns], float),
                np.array([over_tracks(reps[n], key) for n in ns], float).reshape(len(ns), n_boot))
            for f, ns in names.items()}, int(pairs_min or 0)


def compare_searches(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], seed: int = 0) -> dict:
    """The improvement [%] of filter B over filter A (positive: B's error smaller) from
    :func:`search_errors`'s ``(point (K,), replicates (K, n_boot))`` of each: ``point`` (the mean over
    searches of each one's error), ``lo``, ``hi`` (the 95 % percentile interval of the two-level bootstrap:
    each replicate reweights each filter's searches by a with-replacement resample of them, on its run
    resample), ``pair_lo``, ``pair_hi`` (the smallest and largest point improvement over every pair of a
    search of A and a search of B) and ``resolved`` (False: those change sign, the search alone covers 0)."""
    (pa, ra), (pb, rb) = a, b
    n_boot = ra.shape[1]
    rng = np.random.default_rng([int(seed), SEARCH_STREAM])
    wa, wb = resample_counts(len(pa), n_boot, rng), resample_counts(len(pb), n_boot, rng)  # (n_boot, K)
    ma, mb = (wa * ra.T).sum(axis=1) / len(pa), (wb * rb.T).sum(axis=1) / len(pb)
    lo, hi = percentile_ci(improvement(ma, mb))
    pairs = improvement(pa[:, None], pb[None, :])
    resolved = bool(np.all(pairs > 0) or np.all(pairs < 0))
    return {"point": float(improvement(pa.mean(), pb.mean())), "lo": lo, "hi": hi,
            "pair_lo": float(np.min(pairs)), "pair_hi": float(np.max(pairs)), "resolved": resolved}


def signed(x: float) -> str:
    """An improvement with its sign, e.g. ``+1.4 %``, ``-0.0076 %`` (:func:`reports.markdown.fmt_pct`)."""
    return ("+" if x > 0 else "") + fmt_pct(x)


def pick_sentence(record: dict) -> str:
    """Which search's values ``tuned.toml`` (and the tables above) hold per filter (``record["picked"]``), in
    words; "" for a record from before ``--pick``."""
    picked = record.get("picked")
    if not picked:
        return ""
    why = ("the lowest training score (--pick best)" if record.get("pick", "best") == "best"
           else "the first search (--pick first)")
    return (f"`tuned.toml` and the tables above hold, per filter, the search with {why}: "
            + ", ".join(f"{f} search {k}" for f, k in picked.items()) + ".")


def searches_section(out_dir: Path, record: dict, n_boot: int) -> list[str]:
    """The report's lines on ``--repeats K`` (K > 1 with ``record["searches"]``): per filter and search
    the search seed, training score, convergence and held-out error; per filter their spread; each tuned
    filter against the most accurate one over runs and searches. Empty for one search."""
    searches = record.get("searches") or {}
    if int(record.get("repeats", 1) or 1) < 2 or not searches:
        return []
    key = accuracy_key(record)
    name, unit = ACCURACY[key]
    held = load_searches(out_dir, record)
    filters = [f for f in searches if all(f in set(m["filter"]) for _, m, _, _ in held)]
    errs, pairs_min = (search_errors({f: [m for _, m, _, _ in held] for f in filters}, key, n_boot)
                       if held and filters else ({}, 0))
    values = {f"{f}#{k}": float(errs[f][0][i]) for f in errs for i, (k, *_) in enumerate(held)}
    cons = {k: consistency_scores(e, man) for k, _, e, man in held} if record.get("objective") == "consistency" else {}
    rows = []
    for f, ss in searches.items():
        for s in ss:
            k = int(s["search"])
            row = [f, str(k), str(s.get("search_seed", "—")), fmt(s.get("score")),
                   convergence_text(convergence_of(s)), fmt(values.get(f"{f}#{k}", math.nan))]
            rows.append(row + ([fmt(cons.get(k, {}).get(f, math.nan))] if cons else []))
    lines = ["### The searches (`--repeats`)", "",
             f"{record['repeats']} independent searches per filter on the same training runs (search k's sampler "
             "seed below); each search's tuned values run on the same held-out runs "
             f"({', '.join(tuned_dir(k, record) for k, *_ in held)}). "
             f"Held-out {name} [{unit}] by the rule above (t = 0 out, eq 50 per track over the runs no search of any "
             "filter lost, eq 51 over tracks). " + pick_sentence(record), "",
             md_table(["filter", "search", "search seed", "training score", "convergence", f"held-out {name}"]
                      + (["held-out consistency score"] if cons else []), rows), ""]
    if len(held) < int(record["repeats"]):
        lines += [f"Held out: {len(held)} of {record['repeats']} searches (the others' folders are missing: "
                  "rerun `nespm tune` with the same options to add them).", ""]
    if len(held) < 2 or not filters:
        return lines
    spread = []
    for f in filters:
        p = errs[f][0]
        spread.append([f, fmt(float(p.mean())), f"{fmt(float(p.min()))}–{fmt(float(p.max()))}",
                       f"{100 * (p.max() - p.min()) / p.mean():.1f} %"])
    lines += [md_table(["filter", f"mean {name} over searches", "min–max", "spread (max − min, % of the mean)"],
                      spread), ""]
    best = min(filters, key=lambda f: float(errs[f][0].mean()))
    cmp = []
    for f in filters:
        if f == best:
            continue
        c = compare_searches(errs[f], errs[best])
        mark = ci_marks(c["lo"], c["hi"], pairs_min)[2]
        words = (f"{fmt_imprv(c['point'], c['lo'], c['hi'], mark)} over runs and searches; every pair of searches "
                 f"{signed(c['pair_lo'])} to {signed(c['pair_hi'])}" +
                 ("" if c["resolved"] else ": **not resolved by the search**"))
        cmp.append(f"- tuned {best} vs tuned {f}: {best}'s {name} smaller by {words}.")
    lines += ["Tuned A vs tuned B, over the runs and the searches: the improvement of the most accurate tuned "
              f"filter ({best}, the lowest mean over its searches) over each other one, point from the mean over "
              "searches of each search's error; 95 % interval of a two-level bootstrap (each replicate resamples "
              "every filter's searches with replacement and, per track, the runs, the same runs for every search). "
              "*Not resolved by the search*: the point improvement changes sign between pairs of searches (each "
              "search of one filter against each of the other, on the same runs), i.e. the searches' spread "
              "alone covers zero, whatever the runs say. `*`: the interval excludes 0; `†`: fewer than 10 runs on a "
              "track (the runs' resamples too few for the interval).", ""] + cmp + [""]
    return lines


__all__ = ["ACCURACY", "accuracy_key", "compare_searches", "consistency_scores", "convergence_of", "convergence_text",
           "convergence_word", "filter_values", "load_searches", "resolution", "search_errors", "search_tie",
           "pick_sentence", "searches_section", "stopped_short"]
