"""The markdown of a Monte Carlo report: the tables, the published tables beside ours, other folders
beside this one, and the whole ``report.md`` text, verdict first (:func:`render_report`)."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from nespm_cli.reports.all_runs import all_runs_section
from nespm_cli.reports.caveats import caveats, caveats_md
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
from nespm_cli.reports.published import PUBLISHED, published_tables
from nespm_cli.reports.results import filters_in_order, scenario_of, smoother_label
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
)
from nespm_cli.reports.tables import filter_table, horizontal_table
from nespm_cli.reports.verdict import verdict_table
from nespm_cli.reports.verdict_markdown import pairwise_md, verdict_intro, verdict_md
from nespm_cli.reports.tune import training_caveats

__all__ = ["beside_md", "folder_label", "render_report"]

def _nees_cells(nees: float, lo: float, hi: float, word: str) -> list[str]:
    band = DASH if not np.isfinite(lo) else f"[{lo:.2f}, {hi:.2f}]"
    return [fmt(nees, ".2f"), band, word]


def _main_table(table: pd.DataFrame) -> str:
    """Markdown of :func:`filter_table`."""
    ref = table.attrs["reference"]
    min_pairs = table.attrs.get("min_pairs", MIN_PAIRED_RUNS)
    headers = [
        "Method", "VRMSE [m/s]", f"{ref} Imprv.", "95 % CI [%]",
        "MRMSE [rad]", f"{ref} Imprv.", "95 % CI [%]", "mean NEES", "95 % NEES band", "consistency",
        "diverged",
    ]
    rows = []
    for r in table.itertuples(index=False):
        cells = [smoother_label(r.filter) + (" (reference)" if r.is_reference else "")]
        for key in METRICS:
            mark = interval_mark(getattr(r, f"{key}_ci_excludes_0"), r.pairs_min, min_pairs)
            cells += [fmt(getattr(r, key)),
                      *imprv_cells(getattr(r, f"{key}_imprv"), getattr(r, f"{key}_ci_lo"),
                                    getattr(r, f"{key}_ci_hi"), mark)]
        cells += _nees_cells(r.nees, r.nees_lo, r.nees_hi, r.consistency)
        cells.append(f"{r.diverged} / {r.runs}")
        rows.append(cells)
    return md_table(headers, rows)


def _track_md(tt: pd.DataFrame) -> str:
    """Markdown of :func:`track_table`."""
    headers = ["Track", "Method", "VRMSE [m/s]", "MRMSE [rad]", "mean NEES", "95 % NEES band",
               "consistency", "diverged"]
    rows = [
        [str(r.track), smoother_label(r.filter), fmt(r.vrmse), fmt(r.mrmse),
         *_nees_cells(r.nees, r.nees_lo, r.nees_hi, r.consistency), f"{r.diverged} / {r.runs}"]
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
    headers = ["Track", "Method", "distance [m]", "final HPE [m]", "RMS HPE [m]",
               "final HPE [% of distance]", "CEP50 [m]", "R95 [m]", "diverged"]
    rows = [
        ["average" if r.track is None else str(r.track),
         smoother_label(r.filter), fmt(r.distance, ".1f"), fmt(r.hpe_final, ".4g"), fmt(r.hpe_rms, ".4g"),
         fmt(r.hpe_final_pct, ".3g"), fmt(r.cep50, ".3g"), fmt(r.r95, ".3g"), f"{r.diverged} / {r.runs}"]
        for r in ht.itertuples(index=False)
    ]
    return ("Final HPE and its % of distance: mean over the runs no filter lost (per track), then over "
            "tracks; RMS HPE: eq 50 with `sse_hpe` per track and eq 51 over tracks; CEP50 and R95: the "
            "radii holding 50 % and 95 % of those runs' final horizontal errors (per track; mean over "
            "tracks on the average rows); distance: the truth's horizontal distance travelled.\n\n"
            + md_table(headers, rows))


def _published_note(filters: Sequence[str], scenario: str | None, shown: Sequence[dict]) -> str:
    """One line naming the published tables not shown and the filters each needs."""
    missing = [e for e in PUBLISHED.values() if e not in shown]
    if not missing:
        return ""
    needs = "; ".join(f"{e['source']} [scenario `{e['scenario']}`] needs {', '.join(e['values'])}"
                      for e in missing)
    lead = ("No published table has rows for at least two of the filters run "
            if not shown else "Not shown (fewer than two of their filters run, or another scenario) ")
    return f"{lead}({', '.join(filters)}; scenario `{scenario}`): {needs}."


def _published_md(metrics: pd.DataFrame, table: pd.DataFrame, scenario: str | None, n_boot: int,
                  seed: int) -> str:
    """Each published table of the scenario with rows for at least two of the filters run,
    beside ours: the table's methods in its order, our track-averaged VRMSE/MRMSE, the
    improvement of the table's proposed method over each row (ours with its paired 95 %
    interval, and the published one); then one line on the tables not shown."""
    filters = list(table["filter"])
    min_pairs = table.attrs.get("min_pairs", MIN_PAIRED_RUNS)
    entries = published_tables(filters, scenario, min_filters=2)
    note = _published_note(filters, scenario, entries)
    if not entries:
        return note
    intro = (
        "The published numbers come from the real Snapir AUV data (test tracks 5 and 6) with the "
        "authors' recorded IMU and their trained networks; our values on other tracks or data, "
        "or with a synthesized IMU, are not expected to match them closely. Methods we did not "
        f"run show \"{DASH}\". Imprv. is the improvement of the table's proposed method over the "
        "row, 100 (row - proposed) / row, with our paired bootstrap 95 % interval "
        f"({SIG_MARK} = excludes 0, {SMALL_MARK} = too few paired runs to judge)."
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
    return (f"Track average (eq 51) over tracks {', '.join(map(str, tracks))}.\n\n" + md_table(headers, rows))


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
) -> str:
    """The full markdown text of ``report.md``: header, the link to docs/report.md, the Verdict
    (:func:`verdict.verdict_table` of :func:`compare_filters` with ``practical_pct``), the Caveats
    (each once; ``notes``: the figures' own, :func:`mc_figures.figure_notes`), the tables, the
    figures (:func:`mc_figures.figures_md`), the pairwise comparisons, the published tables and
    ``beside`` (the :func:`beside_md` section, if any)."""
    scenario = scenario_of(metrics, manifest)
    ref = table.attrs["reference"]
    comps = compare_filters(metrics, n_boot=n_boot, seed=seed, practical_pct=practical_pct,
                            min_pairs=min_pairs)
    vt = verdict_table(metrics, ref, n_boot=n_boot, seed=seed, practical_pct=practical_pct,
                       min_pairs=min_pairs, comps=comps)
    tracks = int(metrics["track"].nunique())
    return "\n\n".join(
        [
            "# nespm Monte Carlo report",
            header_line(metrics, manifest),
            docs_line(out_dir),
            "## Verdict\n\n" + verdict_intro(ref, n_boot, seed, practical_pct, vt.attrs["any_lost"]) + "\n\n"
            + verdict_md(vt, comps, tracks),
            *([all_runs_section(metrics, ref, n_boot, seed)] if all_runs == "median" and vt.attrs["any_lost"] else []),
            "## Caveats\n\n" + caveats_md(caveats(metrics, comps, min_pairs, [*notes, *training_caveats(manifest)])),
            "## Track-averaged results (eq 51)\n\n" + _main_table(table),
            "## Figures\n\n" + figures_md(figures, out_dir),
            "## Per-track results (eqs 50, 52)\n\n" + _track_md(tt),
            "## Horizontal position error\n\n" + _horizontal_md(metrics),
            "## Pairwise comparisons\n\n" + pairwise_md(comps, min_pairs),
            "## Comparison with the published tables\n\n" + _published_md(metrics, table, scenario, n_boot, seed),
            *(["## Beside other results folders\n\n" + beside] if beside else []),
        ]
    ) + "\n"
