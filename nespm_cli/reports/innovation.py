"""Innovation statistics of a Monte Carlo folder run on tracks without ground truth (a track spec without
``[gt]``, docs/data.md): what ``nespm mc`` and ``nespm tune``'s held-out runs on such tracks measure, and
their report.

Such a folder's manifest says ``"ground_truth": false``; its ``metrics.parquet`` holds, per run, the
engine's numeric loss flag (``diverged``: the only loss known without a truth), per sensor the run's NIS
(``nis_<sensor>``, expectation m, the sensor's dimension) and the negative log-likelihood per row of its
innovations (``nll_<sensor>``, :func:`nespm_cli.experiments.metrics.truth_free_metrics`) and their mean over
the sensors (``innovation_nll``, the innovation objective's L of one run). There is no error, NEES, CEP or
bound: nothing to measure them against, and the report says so in one line
(:data:`nespm_cli.experiments.spec.NO_TRUTH`) instead of printing tables of NaN.

:func:`write_innovation_report` writes an mc folder's ``report.md``; :func:`heldout_innovation_section` is
the held-out part of a ``nespm tune`` report whose held-out tracks have no ground truth.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.data.atomic import write_text_atomic
from nespm_cli.experiments.spec import NO_TRUTH
from nespm_cli.experiments.suite import recorded_dim
from nespm_cli.reports.markdown import fmt, md_table
from nespm_cli.reports.results import read_results_folder


def is_truth_free(out_dir: Path) -> bool:
    """Whether the mc folder ``out_dir`` ran on tracks without ground truth (its manifest says so)."""
    try:
        manifest = json.loads((Path(out_dir) / "manifest.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(manifest, dict) and manifest.get("ground_truth") is False


def sensors_of(metrics: pd.DataFrame) -> list[str]:
    """The sensors with innovation columns (``nll_<sensor>``), in column order."""
    return [c[len("nll_"):] for c in metrics.columns if c.startswith("nll_")]


def innovation_rows(metrics: pd.DataFrame, by_track: bool = False) -> list[dict]:
    """Per filter (and track, ``by_track``): ``runs``, ``lost`` (numeric), and over the runs kept the mean of
    ``nis_<sensor>``, ``nll_<sensor>`` and ``innovation_nll`` (NaN where no run was kept)."""
    keys = ["filter"] + (["track"] if by_track else [])
    cols = [f"{p}_{s}" for s in sensors_of(metrics) for p in ("nis", "nll")] + ["innovation_nll"]
    rows = []
    for key, g in metrics.groupby(keys, sort=False):
        kept = g[~g["diverged"].astype(bool)]
        row = dict(zip(keys, key if isinstance(key, tuple) else (key,)))
        row.update(runs=len(g), lost=int(g["diverged"].astype(bool).sum()))
        row.update({c: float(kept[c].mean()) if len(kept) and c in kept else float("nan") for c in cols})
        rows.append(row)
    return rows


def innovation_table(metrics: pd.DataFrame, manifest: dict, by_track: bool = False) -> str:
    """Markdown of :func:`innovation_rows`: each sensor's NIS with its expectation m (the manifest's
    dimension), its NLL per row, and the mean over sensors."""
    sensors = sensors_of(metrics)
    head = ["filter"] + (["track"] if by_track else []) + ["runs", "lost (numeric)"]
    for s in sensors:
        m = recorded_dim(manifest, s)
        head += [f"NIS {s} (expected {m if m else 'm'})", f"NLL {s} per row"]
    head.append("innovation NLL (mean over sensors)")
    out = []
    for r in innovation_rows(metrics, by_track):
        cells = [r["filter"]] + ([str(r["track"])] if by_track else []) + [str(r["runs"]), str(r["lost"])]
        for s in sensors:
            cells += [fmt(r[f"nis_{s}"], ".3g"), fmt(r[f"nll_{s}"], ".4g")]
        out.append(cells + [fmt(r["innovation_nll"], ".4g")])
    return md_table(head, out)


WHAT = ("Per run: the NIS of each sensor (νᵀ S⁻¹ ν of its measurements, per its full size: expectation m, the "
        "sensor's dimension, for a filter whose noise model is right) and the negative log-likelihood per row of "
        "its innovations, ½ (Σ νᵀ S⁻¹ ν + Σ log det S) / Σ rows (lower: the recorded measurements are more likely "
        "under the filter; comparable between settings and filters on the same runs, not across sensors' "
        "units); the means over the runs the engine did not flag (a non-finite state or covariance, or a speed "
        "above 50 m/s: the only loss known without a truth).")


def write_innovation_report(out_dir: Path) -> Path:
    """Write ``out_dir/report.md`` of an mc folder without ground truth; return its path."""
    out_dir = Path(out_dir)
    metrics, manifest = read_results_folder(out_dir)
    o = manifest.get("options", {}) or {}
    lines = ["# Monte Carlo report", "", f"**{NO_TRUTH[0].upper() + NO_TRUTH[1:]}** (the tracks of "
             f"{o.get('data_dir') or manifest.get('data_dir')} have no ground truth): no error, NEES, CEP or bound, "
             "nothing to measure them against (docs/data.md).", "",
             f"Filters {', '.join(dict.fromkeys(metrics['filter']))} on tracks "
             f"{' '.join(map(str, dict.fromkeys(metrics['track'])))}, {metrics['run'].nunique()} runs each.", "",
             WHAT, "", innovation_table(metrics, manifest), ""]
    if metrics["track"].nunique() > 1:
        lines += ["Per track:", "", innovation_table(metrics, manifest, by_track=True), ""]
    path = out_dir / "report.md"
    write_text_atomic(path, "\n".join(lines))
    return path


def paired_nll(default: pd.DataFrame, tuned: pd.DataFrame, filt: str, n_boot: int, seed: int = 0) -> tuple:
    """``(default, tuned, tuned − default, lo, hi, pairs)``: the mean ``innovation_nll`` of filter ``filt`` over
    the (track, run) pairs neither setting lost, their difference (negative: the tuned setting makes the
    measurements more likely) and its percentile bootstrap 95 % interval over the pairs (``n_boot`` resamples,
    ``seed``)."""
    cols = ["track", "run", "innovation_nll", "diverged"]
    d, t = (x.loc[x["filter"] == filt, cols] for x in (default, tuned))
    m = d.merge(t, on=["track", "run"], suffixes=("_d", "_t"), how="inner")
    m = m[~m["diverged_d"].astype(bool) & ~m["diverged_t"].astype(bool)]
    a, b = m["innovation_nll_d"].to_numpy(float), m["innovation_nll_t"].to_numpy(float)
    if len(a) == 0:
        return (float("nan"),) * 5 + (0,)
    diff = b - a
    idx = np.random.default_rng(seed).integers(0, len(diff), size=(n_boot, len(diff)))
    lo, hi = np.percentile(diff[idx].mean(axis=1), [2.5, 97.5])
    return float(a.mean()), float(b.mean()), float(diff.mean()), float(lo), float(hi), len(diff)


def heldout_innovation_section(out_dir: Path, record: dict, default_dir: str, tuned_dir: str, where: str,
                               n_boot: int) -> list[str]:
    """The held-out part of a tune report on tracks without ground truth: per filter the default against the
    tuned settings on the innovation NLL (paired by run), and each setting's NIS per sensor (``where``: the
    tracks, runs and window)."""
    (default, man_d), (tuned, man_t) = read_results_folder(out_dir / default_dir), read_results_folder(out_dir / tuned_dir)
    rows = []
    for f in dict.fromkeys(default["filter"]):
        d, t, diff, lo, hi, n = paired_nll(default, tuned, f, n_boot)
        rows.append([f, fmt(d, ".4g"), fmt(t, ".4g"), f"{fmt(diff, '+.3g')} [{fmt(lo, '+.3g')}, {fmt(hi, '+.3g')}]",
                     str(n)])
    return [f"## Held out: {where}", "",
            f"**{NO_TRUTH[0].upper() + NO_TRUTH[1:]}**: the held-out tracks have no ground truth, so no error, ANEES "
            "or per-block consistency is shown (docs/tuning.md, \"Tuning without ground truth\").", "",
            "The innovation NLL (the mean over sensors of the negative log-likelihood per row of each run's "
            "innovations) of the default and the tuned settings on the same realizations, over the runs neither "
            "lost, and the tuned minus the default with its bootstrap 95 % interval over the runs (negative: the "
            "tuned filter makes the recorded measurements more likely):", "",
            md_table(["filter", "innovation NLL default", "innovation NLL tuned", "tuned − default [95 %]",
                      "paired runs"], rows), "", WHAT, "",
            "Default:", "", innovation_table(default, man_d), "", "Tuned:", "", innovation_table(tuned, man_t), ""]


__all__ = ["WHAT", "heldout_innovation_section", "innovation_rows", "innovation_table", "is_truth_free",
           "paired_nll", "sensors_of", "write_innovation_report"]
