"""The markdown of a Monte Carlo report: the tables, the published tables beside ours, other folders
beside this one, and the whole ``report.md`` text, verdict first (:func:`render_report`)."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from nespm_cli.reports.all_runs import all_runs_section
from nespm_cli.reports.caveats import caveats, caveats_md, residual_caveats
from nespm_cli.reports.comparisons import compare_filters
from nespm_cli.reports.markdown import (
    DASH,
    SIG_MARK,
    SMALL_MARK,
    docs_line,
    fmt,
    fmt_imprv,
    fmt_pct,
    header_line,
    imprv_cells,
    md_table,
)
from nespm_cli.reports.mc_figures import figures_md
from nespm_cli.reports.oracle_share import has_oracle, oracle_share, share_md
from nespm_cli.reports.pcrb import SECTION as PCRB_SECTION
from nespm_cli.reports.published import PUBLISHED, published_tables
from nespm_cli.reports.block_consistency import consistency_md, consistency_words
from nespm_cli.reports.results import filters_in_order, is_smoother, scenario_of, sensor_dims, smoother_label
from nespm_cli.reports.robust_counts import rejection_md
from nespm_cli.reports.stats import (
    METRICS,
    MIN_PAIRED_RUNS,
    PRACTICAL_PCT,
    ci_marks,
    improvement,
    interval_mark,
    paired_bootstrap,
    paired_improvement,
    paired_run_counts,
    percentile_ci,
    lost_by_any,
    posterior_view,
    track_average,
)
from nespm_cli.reports.tables import filter_table, horizontal_table
from nespm_cli.reports.verdict import consistency_summary, verdict_table
from nespm_cli.reports.verdict_markdown import pairwise_md, verdict_intro, verdict_md
from nespm_cli.reports.tune.report import training_caveats

__all__ = ["beside_md", "folder_label", "render_report"]

#: the caption of the main tables: the t = 0 rule (docs/report.md)
TABLE_CAPTION = ("VRMSE and MRMSE: eq 50 of `anukf.md` (Levy and Klein, \"Adaptive Neural Unscented Kalman "
                 "Filter\"; docs/references.md) per track, eq 51 over tracks; the improvement columns are the papers' "
                 "\"Imprv.\" of the reference over the row. {verdict} {nees} RTS-smoother floors stand in their own "
                 "rows, without an improvement.")
#: what the caption says of the mean NEES: after t = 0 (``nees_post``), or every epoch for a folder without it
NEES_EPOCHS = {True: ("The mean NEES is the mean over the runs not lost of each run's mean NEES over the epochs "
                      "after t = 0 (`nees_post`), as the errors."),
               False: ("The mean NEES is the mean of each run's NEES over every epoch, t = 0 included (1 epoch in "
                       "N; this folder's `metrics.parquet` has no `nees_post`: written by an older nespm).")}
#: what the caption says of the epochs, with the posterior sums and for a folder without them
VERDICT_EPOCHS = {True: ("Every error here, as everywhere in this report, is over the epochs after t = 0 "
                         "(docs/report.md, \"The t = 0 rule\"); the papers' every-epoch values stand only beside the "
                         "published numbers (\"Comparison with the published tables\")."),
                  False: "The verdict's line above says which errors it uses."}  # the fallback is said once, there
PAIRWISE_CAPTION = ("The best filter of each metric against every other filter: its improvement [95 % CI] over the "
                    "runs both kept, the errors as in the verdict.")
CONSISTENCY_CAPTION = (" Consistency: judged per block and sensor from the share of epochs inside the 95 % bounds "
                       "(section \"Consistency per block and sensor\"), not from the mean NEES; where the mean NEES "
                       "lies outside its band, the words say where and name the block that drives it.")


def _nees_cells(nees: float, lo: float, hi: float, word: str) -> list[str]:
    band = DASH if not np.isfinite(lo) else f"[{lo:.2f}, {hi:.2f}]"
    return [fmt(nees, ".2f"), band, word]


def _main_table(table: pd.DataFrame, words: dict | None = None) -> str:
    """Markdown of :func:`filter_table`: the causal filters, then the RTS-smoother floors in their own rows
    (their value only: a floor is no improvement). ``words``: per filter the consistency judged per block
    (:func:`verdict.consistency_summary`: the blocks' words and, with the mean NEES outside its band, the block
    that drives it), else the mean NEES's band word."""
    ref = table.attrs["reference"]
    words = words or {}
    min_pairs = table.attrs.get("min_pairs", MIN_PAIRED_RUNS)
    headers = [
        "Method", "VRMSE [m/s]", f"{ref} Imprv.", "95 % CI [%]",
        "MRMSE [rad]", f"{ref} Imprv.", "95 % CI [%]", "mean NEES", "95 % NEES band", "consistency",
        "diverged",
    ]
    rows = []
    floor = table["filter"].map(is_smoother).to_numpy(bool)
    for r in pd.concat([table[~floor], table[floor]]).itertuples(index=False):
        cells = [smoother_label(r.filter) + (" (reference)" if r.is_reference else "")]
        for key in METRICS:
            mark = interval_mark(getattr(r, f"{key}_ci_excludes_0"), r.pairs_min, min_pairs)
            cells += [fmt(getattr(r, key)),
                      *((DASH, DASH) if is_smoother(r.filter) else
                        imprv_cells(getattr(r, f"{key}_imprv"), getattr(r, f"{key}_ci_lo"),
                                    getattr(r, f"{key}_ci_hi"), mark))]
        cells += _nees_cells(r.nees, r.nees_lo, r.nees_hi, words.get(r.filter, r.consistency))
        cells.append(f"{r.diverged} / {r.runs}")
        rows.append(cells)
    return md_table(headers, rows)


def _track_md(tt: pd.DataFrame, words: dict | None = None) -> str:
    """Markdown of :func:`track_table`; ``words`` per ``(track, filter)`` as in :func:`_main_table`."""
    words = words or {}
    headers = ["Track", "Method", "VRMSE [m/s]", "MRMSE [rad]", "mean NEES", "95 % NEES band",
               "consistency", "diverged"]
    rows = [
        [str(r.track), smoother_label(r.filter), fmt(r.vrmse), fmt(r.mrmse),
         *_nees_cells(r.nees, r.nees_lo, r.nees_hi, words.get((r.track, r.filter), r.consistency)),
         f"{r.diverged} / {r.runs}"]
        for r in tt.itertuples(index=False)
    ]
    return md_table(headers, rows)


def _horizontal_md(metrics: pd.DataFrame) -> str:
    """Markdown of :func:`horizontal_table`, or a note for a folder without the HPE columns."""
    ht = horizontal_table(metrics)
    if ht is None:
        return ("No horizontal-position columns (`hpe_final`, `hpe_rms`, `hpe_final_pct`, ...) in "
                "`metrics.parquet`: the folder was written by an older nespm; re-run `nespm mc` into a "
                "new folder to get them.")
    view = posterior_view(metrics)  # the t = 0 rule: vert_rms_post where the folder has it
    post = bool(view.attrs["posterior"]) and "vert_rms_post" in metrics.columns
    vert = vertical_rms(view)
    headers = ["Track", "Method", "distance [m]", "final HPE [m]", "RMS HPE [m]",
               "final HPE [% of distance]", "CEP50 [m]", "R95 [m]", *(["vertical RMS [m]"] if vert else []),
               "diverged"]
    rows = [
        ["average" if r.track is None else str(r.track),
         smoother_label(r.filter), fmt(r.distance, ".1f"), fmt(r.hpe_final, ".4g"), fmt(r.hpe_rms, ".4g"),
         fmt(r.hpe_final_pct, ".3g"), fmt(r.cep50, ".3g"), fmt(r.r95, ".3g"),
         *([fmt(vert.get((r.track, r.filter)), ".3g")] if vert else []), f"{r.diverged} / {r.runs}"]
        for r in ht.itertuples(index=False)
    ]
    return ("Final HPE and its % of distance: mean over the runs no filter lost (per track), then over "
            "tracks; RMS HPE: eq 50 with `sse_hpe` over the epochs after t = 0 per track and eq 51 over tracks; CEP50 and R95: the "
            "radii holding 50 % and 95 % of those runs' final horizontal errors (per track; mean over "
            "tracks on the average rows); distance: the truth's horizontal distance travelled"
            + (f"; vertical RMS: the RMS over those runs and {VERT_EPOCHS[post]} of the vertical error (eq 51 over "
               "tracks)" if vert else "") + ".\n\n"
            + md_table(headers, rows))


#: the epochs of the vertical RMS: after t = 0 (``vert_rms_post``), or every epoch for a folder without it
VERT_EPOCHS = {True: "the epochs after t = 0 (`vert_rms_post`, as RMS HPE)",
               False: ("every epoch, t = 0 included (this folder's `metrics.parquet` has no `vert_rms_post`; its "
                       "t = 0 error is the initial one, `--pos-v-std`)")}


def nis_md(metrics: pd.DataFrame, manifest: dict) -> str:
    """Without the per-epoch series: per filter and sensor the mean over the common survivors of each run's NIS
    (``nis_<sensor>`` of metrics.parquet) beside its expectation, the sensor's measurement size; not judged
    (a mean is no per-epoch test). Empty without a NIS column."""
    cols = [c for c in metrics.columns if c.startswith("nis_") and np.isfinite(metrics[c].to_numpy(float)).any()]
    if not cols:
        return ""
    dims = sensor_dims(manifest, [c[4:] for c in cols])
    kept = metrics[~lost_by_any(metrics)]
    rows = [[smoother_label(f), c[4:], fmt(float(kept.loc[kept["filter"] == f, c].mean()), ".3g"),
             str(dims.get(c[4:]) or DASH)]
            for f in filters_in_order(metrics) for c in cols if kept.loc[kept["filter"] == f, c].notna().any()]
    return ("No per-epoch series (`epochs.parquet`), so no per-epoch consistency test: the mean over the runs no "
            "filter lost of each run's mean NIS, beside its expectation (the measurement size).\n\n"
            + md_table(["Method", "sensor", "mean NIS", "expected"], rows))


def vertical_rms(metrics: pd.DataFrame) -> dict:
    """``{(track or None, filter): vertical RMS [m]}`` over the runs no filter lost: per track the RMS over the
    runs of each run's ``vert_rms`` (all runs have the same epochs), over tracks eq 51 (key track None); empty
    when no filter has a finite ``vert_rms`` (a folder written before the column)."""
    if "vert_rms" not in metrics.columns or not np.isfinite(metrics["vert_rms"].to_numpy(float)).any():
        return {}
    kept = metrics[~lost_by_any(metrics)]
    per = kept.groupby(["track", "filter"], sort=False)["vert_rms"].apply(
        lambda x: float(np.sqrt(np.mean(np.square(x.to_numpy(float))))))
    out = {(t, f): v for (t, f), v in per.items()}
    for f in filters_in_order(metrics):
        vals = [v for (t, g), v in out.items() if g == f]
        out[(None, f)] = track_average(vals) if vals else float("nan")
    return out


def _published_note(filters: Sequence[str], scenario: str | None, shown: Sequence[dict]) -> str:
    """One line naming the published tables not shown and the filters each needs."""
    missing = [e for e in PUBLISHED.values() if e not in shown]
    if not missing:
        return ""
    needs = "; ".join(f"{e['source']} [scenario `{e['scenario']}`] needs {', '.join(e['values'])}"
                      for e in missing)
    lead = ("No published table has rows for at least two of the filters run "
            if not shown else "Not shown (fewer than two of their filters run, or another scenario) ")
    return (f"{lead}({', '.join(filters)}; scenario `{scenario}`): {needs}. The papers' bibliographic references: "
            "docs/references.md.")


def _published_md(metrics: pd.DataFrame, table: pd.DataFrame, scenario: str | None, n_boot: int,
                  seed: int) -> str:
    """Each published table of the scenario with rows for at least two of the filters run,
    beside ours: the table's methods in its order, our track-averaged VRMSE/MRMSE, the
    improvement of the table's proposed method over each row (ours with its paired 95 %
    interval, and the published one); then one line on the tables not shown."""
    filters = list(table["filter"])
    min_pairs = table.attrs.get("min_pairs", MIN_PAIRED_RUNS)
    table = filter_table(metrics, table.attrs["reference"], n_boot=0, min_pairs=min_pairs, with_t0=True)
    entries = published_tables(filters, scenario, min_filters=2)
    note = _published_note(filters, scenario, entries)
    if not entries:
        return note
    intro = (
        "The published numbers come from the real Snapir AUV data (test tracks 5 and 6) with the "
        "authors' recorded IMU and their trained networks; our values on other tracks or data, "
        "or with a synthesized IMU, are not expected to match them closely. Ours here are the one exception "
        "to the t = 0 rule: computed as the papers define them, over every GT epoch including t = 0, so that "
        "they compare with the published numbers (the rest of this report: after t = 0). Methods we did not "
        f"run show \"{DASH}\". Imprv. is the improvement of the table's proposed method over the "
        "row, 100 (row - proposed) / row, with our paired bootstrap 95 % interval "
        f"({SIG_MARK} = excludes 0, {SMALL_MARK} = too few paired runs to judge). The papers: `anukf.md` = Levy and "
        "Klein, \"Adaptive Neural Unscented Kalman Filter\"; `ukf-nespm.md` = Levy and Klein, \"Unscented Kalman "
        "Filter with a Nonlinear Propagation Model for Navigation Applications\" (University of Haifa; "
        "docs/references.md)."
    )
    parts = [intro]
    ours = {r.filter: r for r in table.itertuples(index=False)}
    for entry in entries:
        ref = entry["reference"]
        pub_ref = entry["values"][ref]
        rows = []
        for name, pub in entry["values"].items():
            r = ours.get(name)
            cells = [name]
            paired = r is not None and ref in ours and name != ref
            boot = paired_bootstrap(metrics, name, ref, n_boot=n_boot, seed=seed) if paired else None
            imp = paired_improvement(metrics, name, ref) if paired else None
            counts = paired_run_counts(metrics, name, ref) if paired else {}
            pairs_min = min(counts.values()) if counts else 0
            for key in METRICS:
                mine = getattr(r, key) if r is not None else None
                cells += [fmt(mine), fmt(pub[key])]
                if name == ref:
                    cells += [DASH, DASH]
                    continue
                if boot is not None:
                    lo, hi = percentile_ci(boot[key])
                    _, _, mark = ci_marks(lo, hi, pairs_min, min_pairs)
                    cells.append(fmt_imprv(imp[key], lo, hi, mark))
                else:
                    cells.append(DASH)
                cells.append(fmt_pct(float(improvement(pub[key], pub_ref[key]))))
            rows.append(cells)
        parts.append(
            f"**{entry['source']}** (scenario `{entry['scenario']}`; Imprv. of {ref})\n\n"
            + md_table(["Method", "VRMSE ours [m/s]", "VRMSE published [m/s]", "Imprv. ours [95 % CI]",
                         "Imprv. published", "MRMSE ours [rad]", "MRMSE published [rad]",
                         "Imprv. ours [95 % CI]", "Imprv. published"], rows)
        )
    if note:
        parts.append(note)
    return "\n\n".join(parts)


def folder_label(out_dir: Path, manifest: dict) -> str:
    """``name (imu ..., dvl ...)`` of a results folder, from its manifest options."""
    o = manifest.get("options", {})
    return f"{Path(out_dir).name} (imu {o.get('imu', '?')}, dvl {o.get('dvl', '?')})"


def beside_md(metrics: pd.DataFrame, label: str, others: Sequence[tuple[str, pd.DataFrame]],
              scenario: str | None = "nominal") -> str:
    """This folder's track-averaged VRMSE / MRMSE / mean NEES beside other folders' (same filter
    names) and the published values (the first published table with the filter).

    ``others``: ``(label, metrics)`` of each other folder. Only tracks in every folder count.
    """
    folders = [(label, metrics), *others]
    common = set(metrics["track"].unique())
    for _, m in others:
        common &= set(m["track"].unique())
    tracks = sorted(common)
    if not tracks:
        return "The folders share no track; nothing to set side by side."
    avgs = [filter_table(m[m["track"].isin(tracks)], None, n_boot=0).set_index("filter")
            for _, m in folders]  # the main table's numbers: eq 51 over the tracks, NEES over all runs
    headers = ["Method"]
    for lab, _ in folders:
        headers += [f"VRMSE [m/s] {lab}", f"MRMSE [rad] {lab}", f"NEES {lab}"]
    headers.append("published VRMSE / MRMSE")
    rows = []
    for f in filters_in_order(metrics):
        row = [f]
        for a in avgs:
            if f in a.index:
                row += [fmt(a.loc[f, "vrmse"]), fmt(a.loc[f, "mrmse"]), fmt(a.loc[f, "nees"], ".3g")]
            else:
                row += ["—", "—", "—"]
        pub = [e for e in PUBLISHED.values() if f in e["values"] and e["scenario"] == scenario]
        row.append(f"{pub[0]['values'][f]['vrmse']:.4g} / {pub[0]['values'][f]['mrmse']:.4g} ({pub[0]['source']})"
                   if pub else "—")
        rows.append(row)
    return (f"Track average (eq 51) over tracks {', '.join(map(str, tracks))}, over the epochs after t = 0 (a folder "
            "without the posterior sums: every epoch); the published values include t = 0.\n\n"
            + md_table(headers, rows))


#: the heading of the section on the robust updates' counts (reports.robust_counts), when a filter has one
ROBUST_SECTION = "## Robust updates: rejected and applied samples"
#: the heading of the section on each adaptive filter's share of its oracle's gain (reports.oracle_share)
ORACLE_SECTION = "## Share of the oracle's gain"


def oracle_md(metrics: pd.DataFrame, n_boot: int, seed: int) -> str:
    """The text of :data:`ORACLE_SECTION` when an oracle is among the filters ("" otherwise): the share
    table of :func:`~nespm_cli.reports.oracle_share.oracle_share`, or why there is none."""
    if not has_oracle(metrics):
        return ""
    text = share_md(oracle_share(metrics, n_boot=n_boot, seed=seed), n_boot)
    return text or ("An oracle is among the filters, but no adaptive filter with its fixed counterpart and that "
                    "filter's oracle (e.g. anekf, iae-ekf, sh-ekf, vb-ekf or aq-ekf with ekf and ekf-oracle).")


def render_report(
    metrics: pd.DataFrame,
    manifest: dict,
    table: pd.DataFrame,
    tt: pd.DataFrame,
    figures: Sequence[Path],
    out_dir: Path,
    n_boot: int,
    seed: int,
    practical_pct: float = PRACTICAL_PCT,
    min_pairs: int = MIN_PAIRED_RUNS,
    beside: str = "",
    notes: Sequence[str] = (),
    all_runs: str = "median",
    consistency: pd.DataFrame | None = None,
    consistency_by_track: pd.DataFrame | None = None,
    pcrb: str = "",
    comps: pd.DataFrame | None = None,
) -> str:
    """The full markdown text of ``report.md``: header, the link to docs/report.md, the Verdict
    (:func:`verdict.verdict_table` of :func:`compare_filters` with ``practical_pct``), the Caveats
    (each once; ``notes``: the figures' own, :func:`mc_figures.figure_notes`), the tables, the
    figures (:func:`mc_figures.figures_md`), the pairwise comparisons, the published tables and
    ``beside`` (the :func:`beside_md` section, if any). ``comps``: :func:`compare_filters` of ``metrics`` with
    these ``n_boot``, ``seed``, ``practical_pct`` and ``min_pairs``, if the caller has it (formed here
    otherwise; :func:`~nespm_cli.reports.mc.write_mc_report` forms it while the figures are drawn)."""
    scenario = scenario_of(metrics, manifest)
    ref = table.attrs["reference"]
    if comps is None:
        comps = compare_filters(metrics, n_boot=n_boot, seed=seed, practical_pct=practical_pct,
                                min_pairs=min_pairs)
    vt = verdict_table(metrics, ref, n_boot=n_boot, seed=seed, practical_pct=practical_pct,
                       min_pairs=min_pairs, comps=comps, consistency=consistency)
    has_blocks = consistency is not None and not consistency.empty
    posterior = bool(vt.attrs["posterior"])
    words = consistency_summary(consistency, metrics, shares=False) if has_blocks else {}
    nees_post = bool(posterior_view(metrics).attrs["posterior_nees"])
    robust = rejection_md(metrics, manifest)
    track_words = consistency_words(consistency_by_track, shares=False) if consistency_by_track is not None else {}
    tracks = int(metrics["track"].nunique())
    return "\n\n".join(
        [
            "# nespm Monte Carlo report",
            header_line(metrics, manifest),
            docs_line(out_dir),
            "## Verdict\n\n" + verdict_intro(ref, n_boot, seed, practical_pct, vt.attrs["any_lost"],
                                                  posterior=vt.attrs["posterior"],
                                                  consistency=consistency.attrs.get("share") if has_blocks else None) + "\n\n"
            + verdict_md(vt, comps, tracks),
            *([all_runs_section(metrics, ref, n_boot, seed)] if all_runs == "median" and vt.attrs["any_lost"] else []),
            "## Caveats\n\n" + caveats_md(caveats(metrics, comps, min_pairs,
                                                    [*notes, *training_caveats(manifest), *residual_caveats(manifest)])),
            "## Track-averaged results (eq 51)\n\n"
            + TABLE_CAPTION.format(verdict=VERDICT_EPOCHS[posterior], nees=NEES_EPOCHS[nees_post])
            + (CONSISTENCY_CAPTION if has_blocks else "") + "\n\n" + _main_table(table, words),
            *(["## Consistency per block and sensor\n\n" + consistency_md(consistency, smoother_label)]
              if has_blocks else ["## Innovations per sensor\n\n" + nis_md(metrics, manifest)]
              if nis_md(metrics, manifest) else []),
            *([ROBUST_SECTION + "\n\n" + robust] if robust else []),
            "## Figures\n\n" + figures_md(figures, out_dir),
            "## Per-track results (eqs 50, 52)\n\n" + _track_md(tt, track_words),
            "## Horizontal position error\n\n" + _horizontal_md(metrics),
            *([PCRB_SECTION + "\n\n" + pcrb] if pcrb else []),
            *([ORACLE_SECTION + "\n\n" + text] if (text := oracle_md(metrics, n_boot, seed)) else []),
            "## Pairwise comparisons\n\n" + PAIRWISE_CAPTION + "\n\n" + pairwise_md(comps, min_pairs),
            "## Comparison with the published tables\n\n" + _published_md(metrics, table, scenario, n_boot, seed),
            *(["## Beside other results folders\n\n" + beside] if beside else []),
        ]
    ) + "\n"
