"""The held-out part of the ``nespm tune`` report (:mod:`nespm_cli.reports.tune.report`): default against tuned settings
on the held-out mc folders (``OUT/heldout-default``, ``OUT/heldout-tuned``) by the mc report's rules.

Per filter the objective's error (the horizontal RMS error with position in the state, else the VRMSE; the
VRMSE beside) over the epochs after t = 0 (eq 50 per track, eq 51 over tracks; paired bootstrap 95 % interval
of the improvement), the ANEES after t = 0 (``nees_post``) against its band, the consistency in the mc report's
one wording (:func:`verdict.consistency_summary`), a line per tuned filter left inconsistent on where a model
parameter (a lever arm) may explain it, the tuned filters against each other (the fair comparison), and with
``--repeats K`` the searches compared (:mod:`nespm_cli.reports.tune.searches`).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.errors import NespmError
from nespm_cli.reports.block_consistency import block_consistency
from nespm_cli.reports.markdown import fmt, fmt_imprv, md_table
from nespm_cli.reports.results import load_results
from nespm_cli.reports.stats import (ci_marks, improvement, nees_check, paired_averages, paired_bootstrap,
                                     paired_improvement, paired_run_counts, percentile_ci, posterior_view)
from nespm_cli.reports.tune.searches import (ACCURACY, accuracy_key, consistency_scores, filter_values, search_tie,
                                             searches_section)
from nespm_cli.reports.verdict import consistency_summary
from nespm_cli.tuning.heldout import DEFAULT_DIR, TUNED_DIR

__all__ = ["fair_rows", "heldout_rows", "heldout_section", "heldout_table", "heldout_words", "model_lines",
           "model_note", "sensor_cells", "window_text"]


def heldout_rows(default: pd.DataFrame, tuned: pd.DataFrame, keys: list[str], n_boot: int) -> list[dict]:
    """Per filter: default against tuned on the same held-out runs, by the mc report's rule for each error
    ``key`` of ``keys`` (``vrmse``, ``hpe``): the posterior sums (t = 0 out, :func:`stats.posterior_view`),
    eq 50 per track over the runs neither lost, eq 51 over tracks; ``{key: (default, tuned, improvement of
    tuned [%], lo, hi, mark)}`` (paired bootstrap 95 % interval, ``†`` under 10 pairs on a track), and
    ``nees`` ({"default", "tuned"}: (the mean per-run NEES over the runs each kept, those runs); each run's mean
    over the epochs after t = 0, ``nees_post``, by the same rule: :func:`stats.posterior_view`), ``lost``,
    ``posterior`` (False: a folder without the posterior sums, every epoch counted), ``posterior_nees`` (False:
    the NEES over every epoch, a folder without ``nees_post``)."""
    rows = []
    for f in sorted(set(default["filter"]) & set(tuned["filter"]), key=list(default["filter"].unique()).index):
        a, b = f"{f} default", f"{f} tuned"
        m = posterior_view(pd.concat([default[default["filter"] == f].assign(filter=a),
                                      tuned[tuned["filter"] == f].assign(filter=b)], ignore_index=True))
        row = {"filter": f, "posterior": bool(m.attrs["posterior"]), "posterior_nees": bool(m.attrs["posterior_nees"]),
               "nees": {}, "lost": {}}
        averages = paired_averages(m, a, b, keys)
        boot = paired_bootstrap(m, a, b, n_boot=n_boot, keys=keys)
        counts = paired_run_counts(m, a, b)
        for k in keys:
            lo, hi = percentile_ci(boot[k])
            row[k] = (*averages[k], float(improvement(*averages[k])), lo, hi,
                      ci_marks(lo, hi, min(counts.values()) if counts else 0)[2])
        for side, name in (("default", a), ("tuned", b)):
            mine = m[m["filter"] == name]
            kept = ~mine["diverged"].astype(bool)
            row["nees"][side] = (float(mine.loc[kept, "nees"].mean()), int(kept.sum()))
            row["lost"][side] = int((~kept).sum())
        rows.append(row)
    return rows


def heldout_table(rows: list[dict], keys: list[str], scores: tuple[dict, dict] | None) -> str:
    """Markdown of :func:`heldout_rows`; ``scores`` (default, tuned) ``{filter: consistency score}`` adds
    the consistency objective's own score beside."""
    head = ["filter"]
    for k in keys:
        name = ACCURACY[k][0]
        head += [f"{name} default", f"{name} tuned", f"{name}: tuned vs default (+: tuned better)"]
    head += (["consistency score default", "consistency score tuned"] if scores else []) + [
        "ANEES default", "ANEES tuned", "lost default", "lost tuned"]
    out = []
    for r in rows:
        cells = [r["filter"]]
        for k in keys:
            d, t, point, lo, hi, mark = r[k]
            cells += [fmt(d), fmt(t), fmt_imprv(point, lo, hi, mark)]
        if scores:
            cells += [fmt(scores[0].get(r["filter"], math.nan)), fmt(scores[1].get(r["filter"], math.nan))]
        for side in ("default", "tuned"):
            nees, n = r["nees"][side]
            lo, hi, word = nees_check(nees, n)
            cells.append(f"{fmt(nees, '.3g')} [{fmt(lo, '.3g')}, {fmt(hi, '.3g')}] {word}")
        out.append(cells + [str(r["lost"]["default"]), str(r["lost"]["tuned"])])
    return md_table(head, out)


def heldout_words(metrics: pd.DataFrame, epochs: pd.DataFrame | None, manifest: dict) -> dict[str, str]:
    """Per filter of a held-out mc folder (its metrics, ``epochs.parquet`` and manifest) the mc report's one
    consistency wording (:func:`verdict.consistency_summary`): the per-block words by the share of epochs
    inside the 95 % bounds (docs/report.md "Consistency") and, with the mean NEES (after t = 0) outside its
    band, where it lies and the block that drives it; without per-epoch columns the mean NEES's band word."""
    table = None if epochs is None else block_consistency(epochs, manifest)
    return consistency_summary(table, metrics)


def fair_rows(tuned: pd.DataFrame, key: str, n_boot: int, record: dict | None = None) -> list[list[str]]:
    """The tuned filters against the most accurate tuned one on error ``key`` (:func:`filter_values`:
    t = 0 out, over the runs no filter lost; improvements paired over the runs each pair kept). ``record``
    (``tune.json``, one search per filter): each comparison the searches cannot rank says so
    (:func:`~nespm_cli.reports.tune.searches.search_tie`)."""
    values = filter_values(tuned, key)
    m = posterior_view(tuned)
    best = min(values, key=values.get)
    rows = []
    for f in sorted(values, key=values.get):
        if f == best:
            rows.append([f, fmt(values[f]), "(reference)"])
            continue
        point = paired_improvement(m, f, best, keys=[key])[key]
        lo, hi = percentile_ci(paired_bootstrap(m, f, best, n_boot=n_boot, keys=[key])[key])
        counts = paired_run_counts(m, f, best)
        tie = search_tie(record, f, best) if record is not None else ""
        rows.append([f, fmt(values[f]), fmt_imprv(point, lo, hi, ci_marks(lo, hi, min(counts.values()))[2])
                     + (f"; **{tie}**" if tie else "")])
    return rows


def sensor_cells(manifest: dict) -> dict[str, dict]:
    """``{sensor: its recorded options}`` of an mc folder's manifest (the first cell holding each)."""
    out: dict[str, dict] = {}
    for cell in (manifest.get("sensors") or {}).values():
        for name, o in (cell.items() if isinstance(cell, dict) else ()):
            if isinstance(o, dict):
                out.setdefault(name, o)
    return out


def model_note(f: str, record: dict, sensors: dict[str, dict]) -> str:
    """Where a model parameter may explain filter ``f``'s tuned held-out inconsistency: per sensor whose
    model reads a lever arm, the lever arm of ``f``'s model (searched, or fixed while the sensor's
    measurements are recorded: a wrong one adds ``ω × l`` in every turn, which no Q, R or P0 covers on
    every track); with every lever arm searched or synthetic, the model parameters ``f`` does not hold;
    and the spread of its training tracks' ANEES at the fitted level."""
    from nespm_cli.filters.options import AXES, lever_key
    from nespm_cli.sensors.registry import get_sensor

    b = record["best"][f]
    searched = {p["key"] for p in record["space"].get(f, []) if p.get("kind") == "model"}
    given = {o[1]: o[2] for o in (record.get("spec") or {}).get("filter_options", []) if o[0] == f}
    parts, open_lever = [], False
    for s, o in sensors.items():
        try:
            if "lever_arm" not in o or not get_sensor(s).has_lever:
                continue
        except NespmError:  # a plugin sensor not loaded here: its model is unknown
            continue
        keys = [lever_key(s, a) for a in AXES]
        arm = [float(b["values"].get(k, given.get(k, v))) for k, v in zip(keys, o["lever_arm"])]
        where = "(" + ", ".join(f"{v:.3g}" for v in arm) + ") m"
        done = [k for k in keys if k in searched]
        if done:
            parts.append(f"its {s} lever arm was searched ({', '.join(done)}): {where}")
        if o.get("source") == "recorded" and len(done) < len(keys):
            open_lever = True
            parts.append(f"its model puts the {s} at {where} from the IMU{' (the other axes fixed)' if done else ''} "
                         f"while the {s} measurements are recorded: a lever arm the model gets wrong adds `ω × l` in "
                         "every turn, an error no Q, R or P0 covers on every track (the embedded and Snapir DVLs sit "
                         f"1.6-2.1 m aft); search it (`--tune-range '*.{lever_key(s, 'x')}=-3:3'`) or give it "
                         f"(`--filter-option {f}.{lever_key(s, 'x')}=...`)")
    recorded = (record.get("spec") or {}).get("imu") == "recorded" or any(
        o.get("source") == "recorded" for o in sensors.values())
    if recorded and not open_lever:
        parts.append("what is left may be a model parameter the filter does not hold (a sensor's time offset, scale "
                     "factor or misalignment: `nespm check` fits them) or held-out tracks unlike the training ones")
    elif not recorded:
        parts.append("its IMU and sensors are synthetic, drawn with its model's lever arms: not a model parameter but "
                     f"the noise's shape or level (the level fitted on {b.get('level_runs', '—')} runs per track "
                     "carries their sampling spread) or held-out tracks unlike the training ones")
    spread = [float(v) for v in (b.get("at_level_tracks") or {}).values() if np.isfinite(v)]
    if len(spread) > 1:
        parts.append(f"its training tracks' ANEES at the level spread from {min(spread):.3g} to {max(spread):.3g} "
                     "(a wide spread: the model misses something the noise cannot cover)")
    text = "; ".join(parts)
    return text[:1].upper() + text[1:]


def model_lines(rows: list[dict], words: dict[str, str], record: dict, sensors: dict[str, dict]) -> list[str]:
    """A line per filter whose tuned settings are not consistent on the held-out runs, with
    :func:`model_note`. ``words``: per filter the one consistency wording (:func:`heldout_words` of the tuned
    folder: a block or sensor by the share rule, or the mean NEES outside its band with the block that drives
    it); a filter without one is judged by its ``rows`` mean NEES's band word (:func:`stats.nees_check`)."""
    lines = []
    for r in rows:
        f = r["filter"]
        word = words.get(f) or nees_check(*r["nees"]["tuned"])[2]
        if word in ("consistent", "—"):
            continue
        lines.append(f"- **{f}** tuned: {word}. {model_note(f, record, sensors)}.")
    if not lines:
        return []
    return ["Where a model parameter may explain it (docs/tuning.md, \"When tuning cannot make a filter "
            "consistent\"):", ""] + lines + [""]


def window_text(record: dict) -> str:
    """The time window the runs used: ``window 0:60 s of each track's GT time`` or ``whole tracks``."""
    w = (record.get("spec") or {}).get("window")
    return f"window {w} s of each track's GT time (`--window`)" if w else "whole tracks"


def heldout_section(out_dir: Path, record: dict, n_boot: int) -> list[str]:
    """"Held out": per filter the default against the tuned settings on the objective's error (and the
    VRMSE beside it), the consistency per block, where a model parameter may explain an inconsistency,
    the tuned filters compared and (``--repeats``) the searches."""
    test = record["test"]
    (default, ep_d, man_d), (tuned, ep_t, manifest) = (load_results(out_dir / DEFAULT_DIR),
                                                       load_results(out_dir / TUNED_DIR))
    key = accuracy_key(record)
    keys = list(dict.fromkeys([key, "vrmse"]))
    rows = heldout_rows(default, tuned, keys, n_boot)
    scores = None
    if record.get("objective") == "consistency":
        scores = (consistency_scores(ep_d, man_d), consistency_scores(ep_t, manifest))
    words_d, words_t = heldout_words(default, ep_d, man_d), heldout_words(tuned, ep_t, manifest)
    epochs = ("the epochs after t = 0 (posterior sums; the mc report's verdict and comparisons, docs/report.md "
              "\"The t = 0 rule\")" if all(r["posterior"] for r in rows) else
              "every epoch including t = 0 (a folder written before the posterior sums: the improvements are "
              "diluted towards 0; rerun `nespm tune` into a new folder)")
    nees_epochs = ("the epochs after t = 0 (`nees_post`)" if all(r["posterior_nees"] for r in rows) else
                   "every epoch including t = 0 (a folder without `nees_post`)")
    name = ACCURACY[key][0]
    own = ("The consistency score is the objective's own (the mean over blocks and sensors of log(ANEES/3)² and "
           "log(ANIS/m)² over the epochs after t = 0, from the per-epoch averages; no interval). "
           if scores else "")
    scored = record.get("objective") in ("rmse", "rmse-consistent")
    what = (f"The {name} ({'the error the objective scores' if scored else 'not scored by this objective'})"
            + ("" if key == "vrmse" else " and the VRMSE beside it"))
    where = (f"tracks {' '.join(map(str, test['tracks']))}, {test['runs']} runs (seed {test['seed']}), "
             f"{window_text(record)}")
    lines = [f"## Held out: {where}", "",
             f"Default and tuned settings on the same realizations. {own}{what}: over {epochs}, eq 50 per track "
             "over the runs neither setting lost, eq 51 over tracks; the improvement of the tuned over the default "
             "paired by run with its bootstrap 95 % interval (`†`: fewer than 10 paired runs on a track, too few "
             "for the interval); ANEES (6 dof) with its 95 % band: the mean over the runs each setting kept of each "
             f"run's mean NEES over {nees_epochs}, as the mc report's.", "", heldout_table(rows, keys, scores), "",
             "Consistency per state block and sensor on the held-out runs, in the mc report's words: the share "
             "of epochs inside the 95 % bounds per block and sensor and, where the mean NEES lies outside its band, "
             "where it lies and the block that drives it:", "",
             md_table(["filter", "default", "tuned"],
                      [[f, words_d.get(f, "—"), words_t.get(f, "—")] for f in dict.fromkeys(default["filter"])]),
             ""]
    lines += model_lines(rows, words_t, record, sensor_cells(manifest))
    many = int(record.get("repeats", 1) or 1) > 1 and record.get("searches")
    lines += ["### The tuned filters compared", "",
              f"Each tuned filter (search 0: `tuned.toml`) against the most accurate one on the {name}, by the same "
              "rule (the runs no filter lost; improvements paired by run). " +
              ("The intervals cover the runs only: the searches below say how much a search's luck moves it."
               if many else "One search per filter: the intervals cover the runs, not the search's luck "
               "(`nespm tune --repeats K` runs K searches and compares over both). Where two filters' training "
               "scores lie within the searches' resolution (the refinement's tolerance, or what a search stopped "
               "short by), the training runs do not rank them and the row says **not resolved by the search**: a held-out "
               "difference within a search's own spread can be where each search stopped (docs/tuning.md, "
               "\"Stability\"); `--repeats K` measures that spread."), "",
              md_table(["filter (tuned)", name, "improvement of the best over it"],
                       fair_rows(tuned, key, n_boot, None if many else record)),
              ""]
    return lines + searches_section(out_dir, record, n_boot)
