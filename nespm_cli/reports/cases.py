"""Comparing studies on the same realizations: ``nespm compare FOLDER...`` (cases of a sensor suite,
tunings, filters added later).

Folders are *cases* of one comparison when their realizations are provably identical: the same
seed, tracks, runs and corruption, the same IMU source and data (equal hashes of every input file
both read), the same data corrections. Sensors, filters, the error-state layout and the filters'
tuning may differ: that is what a case changes. Run ``r`` of track ``N`` then has the same IMU
errors and initial errors in every case, and a sensor present in two cases the same draws (its
own seed stream), so every comparison between cases is paired by ``(track, run)``.

Each (case, filter) becomes one row of the combined metrics under the name ``case/filter``, so
the paired machinery of :mod:`nespm_cli.reports.stats` applies unchanged: the improvement of a
case over the reference case for the same filter, with its paired bootstrap 95 % interval over
the runs neither lost.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.experiments.metrics import cep
from nespm_cli.reports.results import is_smoother
from nespm_cli.reports.stats import (MIN_PAIRED_RUNS, ci_marks, lost_by_any, paired_bootstrap, paired_improvement, paired_run_counts,
                                     percentile_ci, posterior_view, track_average, track_value)

#: options that define the realizations: equal in every case
REALIZATION_KEYS = ("seed", "tracks", "runs", "corruption", "imu", "imu_rate", "data_dir", "window", "corrections",
                    "track_corrections", "imu_axes", "imu_time_offset", "imu_time_drift", "chunk_size")
#: metrics compared between cases (keys of reports.stats.PAIRED_METRICS)
CASE_METRICS = {"hpe": "RMS horizontal error", "hpe_final": "final horizontal error", "vrmse": "velocity RMSE"}
SEP = "/"


@dataclass
class Case:
    """One folder of a comparison: its ``label``, ``metrics`` and ``manifest``."""

    label: str
    folder: Path
    metrics: pd.DataFrame
    manifest: dict


def load_cases(folders, labels=None) -> list[Case]:
    """Read the folders (each a finished ``mc`` folder) as cases, labelled ``labels`` (default: the
    folder names); one line naming the folder if one is not, or if two labels are equal."""
    folders = [Path(f) for f in folders]
    if len(folders) < 2:
        raise NespmError("compare: give at least two results folders")
    labels = list(labels) if labels else [f.name for f in folders]
    if len(labels) != len(folders):
        raise NespmError(f"--labels: {len(labels)} labels for {len(folders)} folders")
    if len(set(labels)) != len(labels) or any(SEP in lab or not lab for lab in labels):
        raise NespmError(f"--labels: give each case a different non-empty label without '{SEP}' ({', '.join(labels)})")
    cases = [load_case(lab, f) for lab, f in zip(labels, folders)]
    check_same_realizations(cases)
    return cases


def load_case(label: str, f: Path) -> Case:
    """One finished ``mc`` folder as a case, read as one consistent state: not while another process
    writes it (a shared lock while reading), only a finished run, tables as assembled and holding every
    run, track and filter the manifest asks for (one line naming the folder otherwise)."""
    from nespm_cli.experiments.snapshot import ReadLock, finished_state
    from nespm_cli.reports.results import check_complete, read_manifest_file, read_parquet

    mf, mp = f / "manifest.json", f / "metrics.parquet"
    if not mp.is_file() or not mf.is_file():
        raise NespmError(f"{f}: not a finished results folder (no metrics.parquet or manifest.json)")
    with ReadLock(f, "compare"):
        manifest = read_manifest_file(mf)
        if manifest.get("experiment", "mc") != "mc" or "sweep" in manifest.get("options", {}):
            raise NespmError(f"{f}: compare takes folders of 'nespm mc' (a sweep compares its own values)")
        finished_state(f, manifest, "compare")  # folders of older versions have no record of their tables
        metrics = read_parquet(mp)
        check_complete(metrics, manifest, mp)
    return Case(label, f, metrics, manifest)


def realization_difference(a: dict, b: dict) -> str | None:
    """The first difference between two manifests that changes the realizations (None: identical):
    an option of :data:`REALIZATION_KEYS`, or an input file both read with other contents."""
    oa, ob = a.get("options", {}), b.get("options", {})
    for k in REALIZATION_KEYS:
        if oa.get(k) != ob.get(k):
            return f"{k} ({json.dumps(oa.get(k))[:60]} vs {json.dumps(ob.get(k))[:60]})"
    ia, ib = a.get("inputs", {}), b.get("inputs", {})
    for path in sorted(set(ia) & set(ib)):
        if ia[path] != ib[path]:
            return f"the contents of {path}"
    return None


def check_same_realizations(cases: list[Case]) -> None:
    """One line naming the first difference if a case's realizations differ from the first case's."""
    ref = cases[0]
    for c in cases[1:]:
        diff = realization_difference(ref.manifest, c.manifest)
        if diff is not None:
            raise NespmError(f"compare: {c.folder} and {ref.folder} are not the same realizations (they differ in "
                             f"{diff}); only folders with the same seed, tracks, runs, corruption and data compare "
                             "run by run")


def combined(cases: list[Case]) -> pd.DataFrame:
    """The cases' metrics in one table, each filter renamed ``case/filter`` (column ``case`` and
    ``base_filter`` keep the parts)."""
    parts = []
    for c in cases:
        m = c.metrics.copy()
        m["case"], m["base_filter"] = c.label, m["filter"]
        m["filter"] = c.label + SEP + m["filter"].astype(str)
        parts.append(m)
    return pd.concat(parts, ignore_index=True)


def _pooled_rms(x: pd.Series) -> float:
    v = x.to_numpy(float)
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v**2))) if v.size else math.nan


def case_table(cases: list[Case]) -> pd.DataFrame:
    """One row per (case, filter), over the runs no filter of that case lost: ``vrmse`` [m/s] and
    ``hpe_rms`` [m] (eq 51 over tracks; over the epochs after t = 0, :func:`stats.posterior_view`, where the
    folder has those sums), ``hpe_final`` [m], ``hpe_final_pct`` [% of the distance
    travelled], ``drift_m_per_h``, ``cep50`` / ``r95`` [m] (final horizontal error, per track then
    averaged), ``vert_rms`` [m] (RMS over runs of the per-run vertical RMS; NaN without a
    position block), ``nis_<sensor>`` (mean per-run NIS of each sensor of the case), ``lost`` and
    ``runs`` (this filter's own losses)."""
    rows = []
    for c in cases:
        m = posterior_view(c.metrics)  # the t = 0 rule (docs/report.md)
        kept = m[~lost_by_any(m)]
        nis_cols = [col for col in m.columns if col.startswith("nis_")]
        for f in dict.fromkeys(m["filter"]):
            mine, own = kept[kept["filter"] == f], m[m["filter"] == f]
            per_track = [(t, g) for t, g in mine.groupby("track", sort=True)]
            row = {"case": c.label, "filter": f, "smoother": is_smoother(f),
                   "vrmse": track_average([track_value(g, "vrmse") for _, g in per_track]),
                   "hpe_rms": track_average([track_value(g, "hpe") for _, g in per_track]),
                   "hpe_final": float(mine["hpe_final"].mean()),
                   "hpe_final_pct": float(mine["hpe_final_pct"].mean()),
                   "drift_m_per_h": float(mine["drift_m_per_h"].mean()) if "drift_m_per_h" in mine else math.nan,
                   "cep50": float(np.mean([cep(g["hpe_final"], 0.5) for _, g in per_track])) if per_track else math.nan,
                   "r95": float(np.mean([cep(g["hpe_final"], 0.95) for _, g in per_track])) if per_track else math.nan,
                   "vert_rms": _pooled_rms(mine["vert_rms"]) if "vert_rms" in mine else math.nan,
                   "lost": int(own["diverged"].sum()), "runs": int(len(own))}
            for col in nis_cols:
                row[col] = float(mine[col].mean()) if mine[col].notna().any() else math.nan
            rows.append(row)
    return pd.DataFrame(rows)


def case_improvements(cases: list[Case], reference: str | None = None, n_boot: int = 2000,
                      seed: int = 0, min_pairs: int = MIN_PAIRED_RUNS) -> pd.DataFrame:
    """For every filter present in the reference case (default: the first) and another case: the
    improvement [%] of the other case over the reference for each metric of :data:`CASE_METRICS`,
    point and paired bootstrap 95 % interval over the runs neither lost (paired by track and run),
    and ``pairs`` (paired runs; ``pairs_min`` the fewest on a track). Positive: the case has the smaller error.
    The same rule as ``nespm report`` (:func:`stats.ci_marks`): ``<key>_significant`` when the interval
    excludes 0 with at least ``min_pairs`` pairs on every track; ``<key>_mark`` ``*``, ``†`` (too few pairs:
    not assessed, whatever the interval) or ``""``. The RMS metrics are posterior (the t = 0 rule) where
    every case has those sums (:func:`stats.posterior_view`)."""
    ref = reference or cases[0].label
    if ref not in [c.label for c in cases]:
        raise NespmError(f"--reference {ref}: not a case label ({', '.join(c.label for c in cases)})")
    m = posterior_view(combined(cases))
    keys = [k for k in CASE_METRICS if k != "hpe" or "sse_hpe" in m.columns]
    rows = []
    ref_filters = list(dict.fromkeys(m.loc[m["case"] == ref, "base_filter"]))
    for c in cases:
        if c.label == ref:
            continue
        for f in ref_filters:
            a, b = f"{c.label}{SEP}{f}", f"{ref}{SEP}{f}"
            if a not in set(m["filter"]):
                continue
            sub = m[m["filter"].isin([a, b])]
            point = paired_improvement(sub, b, a, keys)  # improvement of a (the case) over b (the reference)
            boot = paired_bootstrap(sub, b, a, n_boot=n_boot, seed=seed, keys=keys)
            counts = paired_run_counts(sub, b, a)
            pairs_min = min(counts.values()) if counts else 0
            row = {"case": c.label, "reference": ref, "filter": f, "pairs": int(sum(counts.values())),
                   "pairs_min": pairs_min}
            for k in keys:
                lo, hi = percentile_ci(boot[k])
                _, significant, mark = ci_marks(lo, hi, pairs_min, min_pairs)
                row.update({k: point[k], f"{k}_lo": lo, f"{k}_hi": hi, f"{k}_significant": significant,
                            f"{k}_mark": mark})
            rows.append(row)
    return pd.DataFrame(rows)


__all__ = ["CASE_METRICS", "Case", "REALIZATION_KEYS", "case_improvements", "case_table", "check_same_realizations",
           "combined", "load_case", "load_cases", "realization_difference"]
