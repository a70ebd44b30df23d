"""The A-KIT question on the recorded data (``make akit``; docs/learned.md, "The A-KIT protocol"):
one table from the folders the target writes, and whether the published gains reproduce in kind.

A-KIT (Cohen & Klein, arXiv 2401.09987) reports that its learned process noise "outperforms the
conventional EKF by more than 49.5 % and model-based adaptive EKF by 35.4 % in position". The
target runs the filters on A-KIT's test tracks in three ``nespm mc`` folders on the same
realizations (checked: :func:`nespm_cli.reports.cases.load_cases`), read here as the cases of
:data:`CASES` under one results folder:

* ``mc``: the EKF with its defaults, the model-based adaptive EKFs (``iae-ekf``, ``sh-ekf``,
  ``vb-ekf``) and ``anekf`` with the ProcessNet the target trained;
* ``mc-tuned``: the same five filters, each with the values ``nespm tune`` found for it on the
  training tracks (every filter searched with the same budget);
* ``mc-onnx``: ``anekf`` with the same ProcessNet exported to ONNX.

Every number is computed by the library's statistics (:mod:`nespm_cli.reports.stats`) on the
combined metrics: over the runs no row lost, the posterior sums (the epochs after t = 0,
docs/filters.md), eq 50 per track, eq 51 over tracks; improvements paired by (track, run) with
percentile-bootstrap 95 % intervals.

Run ``python -m nespm_cli.reports.akit_table RESULTS [--readme README.md]``: writes
``RESULTS/akit-table.md`` and replaces the lines between :data:`BEGIN` and :data:`END` in the
README (one line naming the file if a folder or a marker is missing; exit 2).
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.data.atomic import write_text_atomic
from nespm_cli.errors import NespmError
from nespm_cli.reports.cases import SEP, combined, load_cases
from nespm_cli.reports.markdown import DASH, fmt, fmt_imprv, md_table
from nespm_cli.reports.stats import (ci_marks, lost_by_any, over_tracks, paired_bootstrap, paired_improvement,
                                     paired_run_counts, percentile_ci, posterior_view, track_value)

BEGIN = "<!-- akit-table:begin -->"
END = "<!-- akit-table:end -->"
#: case label -> subfolder of the results folder
CASES = {"default": "mc", "tuned": "mc-tuned", "onnx": "mc-onnx"}
#: (row label, combined filter name), in table order
ROWS = (("EKF, default", "default/ekf"), ("EKF, tuned", "tuned/ekf"), ("IAE-EKF", "default/iae-ekf"),
        ("IAE-EKF, tuned", "tuned/iae-ekf"), ("SH-EKF", "default/sh-ekf"), ("SH-EKF, tuned", "tuned/sh-ekf"),
        ("VB-EKF", "default/vb-ekf"), ("VB-EKF, tuned", "tuned/vb-ekf"), ("ANEKF (ProcessNet)", "default/anekf"),
        ("ANEKF (ProcessNet), tuned", "tuned/anekf"), ("ANEKF (ONNX export)", "onnx/anekf"))
DEFAULT_EKF, TUNED_EKF, LEARNED, TUNED_LEARNED = "default/ekf", "tuned/ekf", "default/anekf", "tuned/anekf"
MODEL_BASED = ("default/iae-ekf", "default/sh-ekf", "default/vb-ekf")
TUNED_MODEL_BASED = ("tuned/iae-ekf", "tuned/sh-ekf", "tuned/vb-ekf")
#: A-KIT's published position gains [%]: over the EKF, over the model-based adaptive EKF
PUBLISHED = {"ekf": 49.5, "model": 35.4}
#: "in kind": a significant gain of at least this share of the published one
KIND_SHARE = 0.5
KEYS = ("hpe", "hpe_final", "vrmse")
N_BOOT = 2000


@dataclass
class Gain:
    """Improvement [%] of a row over a reference on the metric ``hpe`` (RMS horizontal position
    error): point, 95 % interval ``lo``, ``hi``, ``significant`` (interval excludes 0 with enough pairs)."""

    point: float
    lo: float
    hi: float
    significant: bool
    mark: str

    def text(self) -> str:
        return fmt_imprv(self.point, self.lo, self.hi, self.mark)


def load_metrics(results: Path) -> tuple[pd.DataFrame, dict]:
    """The combined metrics of the three folders (filters named ``case/filter``), posterior view,
    and the default folder's manifest. One line naming the folder if one is missing."""
    results = Path(results)
    folders = [results / sub for sub in CASES.values()]
    for f in folders:
        if not (f / "metrics.parquet").is_file():
            raise NespmError(f"akit table: {f}: no metrics.parquet (run make akit first)")
    cases = load_cases(folders, list(CASES))
    m = posterior_view(combined(cases))
    missing = [name for _, name in ROWS if name not in set(m["filter"])]
    if missing:
        raise NespmError(f"akit table: {results}: no results for {', '.join(missing)}")
    return m[m["filter"].isin([name for _, name in ROWS])].reset_index(drop=True), cases[0].manifest


def row_values(m: pd.DataFrame, name: str) -> dict:
    """One row's numbers over the runs no row of ``m`` lost: ``hpe`` [m] (eq 50 per track, 51 over
    tracks), ``hpe_final`` [m] and ``hpe_final_pct`` [% of the distance] (mean per track, then over
    tracks), ``vrmse`` [m/s], ``nees`` (mean per-run NEES, 6 dof: mean per track, then over tracks);
    ``counted`` runs and the row's own ``lost`` runs; ``q_factor_acc``, ``q_factor_gyro`` (an adaptive
    filter's mean predicted noise std over the nominal, NaN for the others)."""
    kept = m[~lost_by_any(m)]
    mine, own = kept[kept["filter"] == name], m[m["filter"] == name]
    per_track = [g for _, g in mine.groupby("track", sort=True)]
    out = {k: over_tracks([track_value(g, k) for g in per_track], k) for k in KEYS}
    for col in ("hpe_final_pct", "nees", "q_factor_acc", "q_factor_gyro"):
        out[col] = float(np.mean([g[col].mean() for g in per_track])) if per_track else math.nan
    out["counted"], out["lost"] = int(len(mine)), int(own["diverged"].sum())
    return out


def gain(m: pd.DataFrame, ref: str, row: str, key: str = "hpe", n_boot: int = N_BOOT) -> Gain:
    """Paired improvement of ``row`` over ``ref`` on ``key`` [%] with its bootstrap 95 % interval
    (:func:`stats.paired_bootstrap`; positive: ``row`` has the smaller error)."""
    sub = m[m["filter"].isin([ref, row])]
    point = paired_improvement(sub, ref, row, [key])[key]
    lo, hi = percentile_ci(paired_bootstrap(sub, ref, row, n_boot=n_boot, keys=[key])[key])
    counts = paired_run_counts(sub, ref, row)
    _, significant, mark = ci_marks(lo, hi, min(counts.values()) if counts else 0)
    return Gain(point, lo, hi, significant, mark)


def in_kind(g: Gain, published: float) -> str:
    """Words for a gain against a published one: reproduced in kind (significant, at least
    :data:`KIND_SHARE` of it), the sign only, or not."""
    if g.significant and g.point >= KIND_SHARE * published:
        return "reproduces in kind"
    if g.significant and g.point > 0:
        return "same sign, far smaller"
    if g.significant:
        return "opposite sign"
    return "no significant gain"


def setup_line(results: Path) -> str | None:
    """Where the learned model and the tuned filters come from, read from ``processnet.npz`` (its training
    record) and ``tune/tune.json``; None where either is absent (e.g. folders made by hand)."""
    import json

    from nespm_cli.learn.processnet import load_nets

    npz, tune = results / "processnet.npz", results / "tune" / "tune.json"
    if not (npz.is_file() and tune.is_file()):
        return None
    try:
        meta = load_nets(npz)[1]
        t = json.loads(tune.read_text(encoding="utf-8"))
        cfg, test, on = meta["config"], meta["test"], t["tuned_on"]
        tracks = lambda ts: ", ".join(str(x) for x in ts)  # noqa: E731
        return (f"ProcessNet trained on tracks {tracks(cfg['train_tracks'])} ({cfg.get('imu', 'synthetic')} IMU, "
                f"{cfg['runs']} realizations per track; Spearman of its std against the injected one on tracks "
                f"{tracks(cfg['test_tracks'])}: accelerometer {test['acc']['spearman']:.3f}, gyro "
                f"{test['gyro']['spearman']:.3f}); {', '.join(t['space'])} each tuned by `nespm tune` on tracks "
                f"{tracks(on['tracks'])} ({t['trials']} trials each, {on['runs'][1] - on['runs'][0]} runs per track, "
                f"objective {t['objective']}).")
    except (KeyError, TypeError, ValueError, OSError) as exc:
        raise NespmError(f"akit table: {npz} or {tune}: not the record of nespm train / nespm tune ({exc})") from None


def search_line(results: Path) -> str | None:
    """The tuning's cross-check (``tune/tune.json``, docs/tuning.md): which filters' searches stopped
    short (another filter's searched values score better than their own best on the training runs,
    by more than :data:`~nespm_cli.tuning.profile.FLAT`); None without the record or the check."""
    import json

    from nespm_cli.tuning.profile import FLAT, stopped_short

    tune = results / "tune" / "tune.json"
    if not tune.is_file():
        return None
    try:
        best = json.loads(tune.read_text(encoding="utf-8"))["best"]
        if not any("cross" in b for b in best.values()):
            return None
        short = [f"{f} ({g}'s values {100 * c['gain']:.0f} % better)" for f, (g, c) in stopped_short(best).items()]
    except (KeyError, TypeError, ValueError, OSError) as exc:
        raise NespmError(f"akit table: {tune}: not the record of nespm tune ({exc})") from None
    if not short:
        return (f"**The searches** (the tuning report's cross-check): no filter's own best is beaten by another's "
                f"searched values on the training runs (by more than {100 * FLAT:.0f} %).")
    return (f"**The searches** (the tuning report's cross-check): another filter's searched values score better on "
            f"the training runs for {', '.join(short)}: those searches stopped short, so a tuned row's rank against "
            "theirs reflects the search as much as the filter (docs/tuning.md).")


def table(results: str | Path, n_boot: int = N_BOOT) -> tuple[str, dict]:
    """The markdown of the A-KIT table and its numbers (``rows``: label -> values and gains;
    ``summary``: the gains behind the final lines)."""
    m, manifest = load_metrics(Path(results))
    rows, cells = {}, []
    for label, name in ROWS:
        v = row_values(m, name)
        v["over_default"] = None if name == DEFAULT_EKF else gain(m, DEFAULT_EKF, name, n_boot=n_boot)
        v["over_tuned"] = None if name == TUNED_EKF else gain(m, TUNED_EKF, name, n_boot=n_boot)
        rows[label] = v
        cells.append([label, fmt(v["hpe"], ".3f"), f"{fmt(v['hpe_final'], '.2f')} ({fmt(v['hpe_final_pct'], '.2f')} %)",
                      fmt(v["vrmse"], ".4f"), fmt(v["nees"], ".2f"),
                      v["over_default"].text() if v["over_default"] else DASH,
                      v["over_tuned"].text() if v["over_tuned"] else DASH, f"{v['counted']} / {v['lost']}"])
    hpe = {name: rows[label]["hpe"] for label, name in ROWS}
    best_model = min(MODEL_BASED, key=hpe.get)
    g_ekf, g_model, g_tuned = rows["ANEKF (ProcessNet)"]["over_default"], gain(m, best_model, LEARNED, n_boot=n_boot), \
        rows["ANEKF (ProcessNet)"]["over_tuned"]
    share = g_tuned.point / g_ekf.point * 100.0 if g_ekf.point > 0 else math.nan
    best_tuned_model = min(TUNED_MODEL_BASED, key=hpe.get)
    g_fair, g_fair_model = rows["ANEKF (ProcessNet), tuned"]["over_tuned"], gain(m, best_tuned_model, TUNED_LEARNED,
                                                                                   n_boot=n_boot)
    summary = {"over_ekf": g_ekf, "over_model": g_model, "best_model": best_model, "over_tuned": g_tuned,
               "share_pct": share, "tuned_over_tuned": g_fair, "best_tuned_model": best_tuned_model,
               "tuned_over_tuned_model": g_fair_model}
    opts = manifest.get("options", {})
    runs, tracks = opts.get("runs"), opts.get("tracks")
    imu = opts.get("imu", "synthetic")
    corr = opts.get("corrections")
    head = (f"Tracks {', '.join(str(t) for t in tracks or [])}, {runs} runs per track (seed {opts.get('seed')}), "
            f"{imu} IMU" + (f" with the corrections of `{Path(corr).name}`" if corr else "") + ", schedule "
            f"{opts.get('corruption', {}).get('schedule', DASH)}; every filter on the same runs "
            f"(`{'`, `'.join(str(Path(results) / s) for s in CASES.values())}`).")
    headers = ["filter", "HPE RMS [m]", "final HPE [m] (% of distance)", "velocity RMSE [m/s]", "mean NEES",
               "HPE RMS gain over default EKF [95 %]", "over tuned EKF [95 %]", "runs counted / lost"]
    tuning = rows["EKF, tuned"]["over_default"]
    if not np.isfinite(share):
        share_text = DASH + " (no gain over the default EKF to keep)"
    elif share < 0:
        share_text = (f"none (the ratio is {share:.0f} %: ANEKF's HPE RMS is {-g_tuned.point:.1f} % above the "
                      "tuned EKF's)")
    elif share > 100 and tuning.point < 0:
        share_text = (f"{share:.0f} % (more than all of it: the tuned EKF's HPE RMS is {-tuning.point:.1f} % above "
                      "the default's on these runs)")
    else:
        share_text = f"{share:.0f} %"
    learned = rows["ANEKF (ProcessNet)"]
    searches = search_line(Path(results))
    tail = [
        f"**Published gains in kind?** ANEKF's HPE RMS gain over the default EKF: {g_ekf.text()} (A-KIT: more than "
        f"{PUBLISHED['ekf']} %): {in_kind(g_ekf, PUBLISHED['ekf'])}; over the best model-based adaptive EKF "
        f"({best_model.split(SEP)[1]}): {g_model.text()} (A-KIT: {PUBLISHED['model']} %): "
        f"{in_kind(g_model, PUBLISHED['model'])}. **Left over the tuned EKF:** {g_tuned.text()}; the share of "
        f"the gain over the default EKF that remains: {share_text}. **Every filter tuned with the same "
        f"budget** (the fair comparison): the tuned ANEKF over the tuned EKF {g_fair.text()}, over the best tuned "
        f"model-based adaptive EKF ({best_tuned_model.split(SEP)[1]}) {g_fair_model.text()}.",
        *([searches] if searches else []),
        f"ANEKF's learned noise std, mean over runs and DVL intervals, in multiples of the nominal: "
        f"accelerometer {fmt(learned['q_factor_acc'], '.2f')}, gyro {fmt(learned['q_factor_gyro'], '.2f')} "
        f"(the validity clip is 0.25-24). Mean NEES: 6 is consistent.",
    ]
    setup = setup_line(Path(results))
    text = "\n\n".join([head + (" " + setup if setup else ""), md_table(headers, cells), *tail,
                        "Gains: paired by run, positive = smaller error than the reference, `*` the 95 % "
                        "interval excludes 0, `†` too few runs to judge (docs/report.md)."]) + "\n"
    return text, {"rows": rows, "summary": summary}


def replace_between_markers(path: Path, text: str) -> None:
    """Put ``text`` between the :data:`BEGIN` and :data:`END` lines of ``path`` (one line naming the
    file if it cannot be read or lacks a marker)."""
    try:
        old = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise NespmError(f"--readme {path}: cannot read ({exc.strerror})") from None
    i, j = old.find(BEGIN), old.find(END)
    if i < 0 or j < i:
        raise NespmError(f"--readme {path}: no '{BEGIN}' line followed by '{END}'")
    write_text_atomic(path, old[:i + len(BEGIN)] + "\n" + text + old[j:])


def write(results: str | Path, readme: str | Path | None = None, n_boot: int = N_BOOT) -> str:
    """Write ``RESULTS/akit-table.md`` and, if given, the README's table; return the markdown."""
    text, _ = table(results, n_boot)
    write_text_atomic(Path(results) / "akit-table.md", "# The A-KIT question on the recorded data\n\n" + text)
    if readme is not None:
        replace_between_markers(Path(readme), text)
    return text


def main(argv: list[str] | None = None) -> int:
    """``python -m nespm_cli.reports.akit_table RESULTS [--readme FILE]``; errors as one line, exit 2."""
    args = list(sys.argv[1:] if argv is None else argv)
    readme = None
    if "--readme" in args:
        k = args.index("--readme")
        if k + 1 >= len(args):
            print("nespm: error: --readme needs a file", file=sys.stderr)
            return 2
        readme = args.pop(k + 1)
        args.pop(k)
    if len(args) != 1:
        print("nespm: error: usage: python -m nespm_cli.reports.akit_table RESULTS [--readme FILE]", file=sys.stderr)
        return 2
    try:
        write(args[0], readme)
    except NespmError as exc:
        print(f"nespm: error: {exc}", file=sys.stderr)
        return 2
    print(f"akit table: {Path(args[0]) / 'akit-table.md'}" + (f", {readme}" if readme else ""))
    return 0


__all__ = ["BEGIN", "CASES", "END", "Gain", "PUBLISHED", "ROWS", "gain", "in_kind", "load_metrics", "main",
           "replace_between_markers", "row_values", "setup_line", "table", "write"]

if __name__ == "__main__":
    sys.exit(main())
