"""The markdown of a sweep report: per-value tables, the improvement tables and the whole
``report.md`` text, verdict first (:func:`render_sweep_report`)."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from nespm_cli.experiments.metrics import nees_band
from nespm_cli.reports.all_runs import all_runs_section
from nespm_cli.reports.caveats import caveats, caveats_md, residual_caveats
from nespm_cli.reports.markdown import DASH, docs_line, fmt, fmt_imprv, header_line, md_table
from nespm_cli.reports.results import filters_in_order, smoother_label
from nespm_cli.reports.stats import MIN_PAIRED_RUNS, NEES_DOF, PRACTICAL_PCT
from nespm_cli.reports.sweep_data import param_label, param_of, protocol_text, sweep_values
from nespm_cli.reports.sweep_tables import improvement_points, nees_runs, summary_rows, sweep_verdict
from nespm_cli.reports.verdict_markdown import pairwise_md, verdict_intro, verdict_md

__all__ = ["render_sweep_report"]

def _cell(v: float, lo: float, hi: float, spec: str = ".4g") -> str:
    """``value [lo, hi]``; just the value when the interval is undefined; dash for NaN."""
    if not np.isfinite(v):
        return DASH
    if np.isfinite(lo) and np.isfinite(hi):
        return f"{fmt(v, spec)} [{fmt(lo, spec)}, {fmt(hi, spec)}]"
    return fmt(v, spec)


def _metric_md(table: pd.DataFrame, key: str, filters: Sequence[str], xlabel: str) -> str:
    rows = []
    for v, d in table.groupby("value", sort=True):
        d = d.set_index("filter")
        cells = [f"{v:g}"]
        for f in filters:
            r = d.loc[f]
            if key == "div_rate":
                cells.append(DASH if r["runs"] == 0 else
                             f"{_cell(r['div_rate'], r['div_rate_lo'], r['div_rate_hi'], '.2f')} "
                             f"({int(r['diverged'])}/{int(r['runs'])})")
            else:
                spec = ".2f" if key == "nees" and abs(r[key]) < 100 else ".4g"
                cells.append(_cell(r[key], r[f"{key}_lo"], r[f"{key}_hi"], spec))
        rows.append(cells)
    return md_table([xlabel] + [smoother_label(f) for f in filters], rows)


def _improvement_md(imp: pd.DataFrame, key: str, filters: Sequence[str], xlabel: str) -> str:
    """Rows = values, columns = filters: ``point % [lo, hi] mark`` from :func:`improvement_points`."""
    values = sorted(pd.unique(imp["value"]))
    cols = {f: improvement_points(imp, key, f).set_index("value") for f in filters}
    rows = []
    for v in values:
        cells = [f"{v:g}"]
        for f in filters:
            r = cols[f].loc[v]
            cells.append(fmt_imprv(r["imprv"], r["ci_lo"], r["ci_hi"], r["mark"]))
        rows.append(cells)
    return md_table([xlabel] + [smoother_label(f) for f in filters], rows)


def render_sweep_report(
    metrics: pd.DataFrame,
    manifest: dict,
    table: pd.DataFrame,
    imp: pd.DataFrame,
    figures: Sequence[Path],
    out_dir: Path,
    n_boot: int,
    seed: int,
    practical_pct: float = PRACTICAL_PCT,
    comps: pd.DataFrame | None = None,
    all_runs: str = "median",
) -> str:
    """The full markdown text of a sweep's ``report.md``, verdict first (``comps``: :func:`summary_rows`,
    computed here when not given): the verdict per value (:func:`verdict.verdict_table` of each value),
    the caveats once, the per-value tables and figures, the improvement over the baseline, the
    pairwise comparisons."""
    min_pairs = imp.attrs.get("min_pairs", MIN_PAIRED_RUNS)
    if comps is None:
        comps = summary_rows(metrics, n_boot=n_boot, seed=seed, practical_pct=practical_pct,
                             min_pairs=min_pairs)
    param = param_of(metrics)
    label = param_label(param)
    values = sweep_values(metrics)
    filters = filters_in_order(metrics)
    base = imp.attrs["baseline"]
    others = [f for f in filters if f != base]
    n = nees_runs(metrics)
    blo, bhi = nees_band(NEES_DOF, n)
    proto = protocol_text(metrics, manifest)
    figs = {Path(p).stem: Path(p).relative_to(out_dir).as_posix() for p in figures}

    def fig(stem: str) -> str:
        return f"\n\n![{stem}]({figs[stem]})" if stem in figs else ""

    header = (
        f"**Sweep:** parameter `{param}` ({label}); values {', '.join(f'{v:g}' for v in values)}; "
        f"baseline `{base}`" + (f"; protocol: {proto}" if proto else "") + "."
    )
    div_lines = []
    for r in table[table["diverged"] > 0].itertuples(index=False):  # values ascending
        if r.diverged == r.runs:
            div_lines.append(f"- value {r.value:g}, `{r.filter}`: every run diverged "
                             f"({r.diverged}/{r.runs}); its error metrics are undefined ({DASH}).")
        else:
            div_lines.append(f"- value {r.value:g}, `{r.filter}`: {r.diverged} of {r.runs} runs "
                             "diverged (lost) and are left out of every filter's error metrics.")
    div_text = "\n".join(div_lines) if div_lines else "No run diverged."
    vt = sweep_verdict(metrics, base, n_boot=n_boot, seed=seed, practical_pct=practical_pct, min_pairs=min_pairs,
                       comps=comps)
    tracks = int(metrics["track"].nunique())
    sections = [
        f"# nespm sweep report: {param}",
        header,
        header_line(metrics, manifest),
        docs_line(out_dir),
        "## Verdict\n\n" + verdict_intro(base, n_boot, seed, practical_pct, vt.attrs["any_lost"], "baseline",
                                                  posterior=vt.attrs.get("posterior"))
        + " Per swept value.\n\n" + verdict_md(vt, comps, tracks, value_col=label, role="baseline"),
        *([all_runs_section(metrics, base, n_boot, seed, value_label=label)]
          if all_runs == "median" and vt.attrs["any_lost"] else []),
        "## Caveats\n\n" + caveats_md(caveats(metrics, comps, min_pairs, residual_caveats(manifest))),
        "## Track-averaged VRMSE [m/s] (eqs 50–51, after t = 0)\n\n"
        + _metric_md(table, "vrmse", filters, label) + fig("sweep_vrmse"),
        "## Track-averaged MRMSE [rad] (eqs 51–52, after t = 0)\n\n"
        + _metric_md(table, "mrmse", filters, label) + fig("sweep_mrmse"),
        "## Mean NEES (6 DOF)\n\n"
        f"95 % consistency band for {n} runs: **[{blo:.2f}, {bhi:.2f}]** "
        f"(`nees_band(6, {n})`, i.e. χ²₍{NEES_DOF * n}₎ quantiles / {n}): above it overconfident, below "
        "conservative. A mean inside it is a lenient test, not the per-block judgment of a Monte Carlo report "
        "(docs/report.md, \"Consistency\"), which needs the per-epoch series a sweep report does not read.\n\n"
        + _metric_md(table, "nees", filters, label) + fig("sweep_nees"),
        "## Divergences\n\nRate `diverged / runs` [95 % Wilson interval] (count).\n\n"
        + _metric_md(table, "div_rate", filters, label) + "\n\n" + div_text + fig("sweep_divergence"),
        f"## Improvement over `{base}` [%] (paired 95 % interval)\n\n"
        + ("**VRMSE**\n\n" + _improvement_md(imp, "vrmse", others, label)
           + "\n\n**MRMSE**\n\n" + _improvement_md(imp, "mrmse", others, label)
           if others else "Only one filter: no improvement to show.")
        + fig("sweep_improvement"),
        "## Pairwise comparisons\n\nPer value, head to head on the runs both filters kept: the best filter and "
        "its paired improvement [95 % CI] over each other filter.\n\n" + pairwise_md(comps, min_pairs),
    ]
    return "\n\n".join(sections) + "\n"


