"""The report of ``nespm compare``: a table per case and filter, the paired improvements over the
reference case, and one figure (:mod:`nespm_cli.reports.cases` holds the analysis)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.experiments.progress import phase
from nespm_cli.reports.cases import CASE_METRICS, Case, case_improvements, case_table, load_cases
from nespm_cli.reports.figures import filter_colors, save_figure, use_agg
from nespm_cli.reports.markdown import SIG_MARK, SMALL_MARK, fmt, fmt_imprv, layout_text, md_table, sensors_text
from nespm_cli.reports.stats import MIN_PAIRED_RUNS, has_posterior

#: the case table's columns: (column, header)
TABLE_COLUMNS = (("vrmse", "VRMSE [m/s]"), ("hpe_rms", "HPE RMS [m]"), ("hpe_final", "HPE final [m]"),
                 ("hpe_final_pct", "final, % of DT"), ("drift_m_per_h", "drift [m/h]"), ("cep50", "CEP50 [m]"),
                 ("r95", "R95 [m]"), ("vert_rms", "vertical RMS [m]"))


def case_table_md(table: pd.DataFrame) -> str:
    """The per (case, filter) table, with each sensor's mean NIS (its dimension in brackets where known)."""
    nis = [c for c in table.columns if c.startswith("nis_")]
    headers = ["case", "filter", *(h for _, h in TABLE_COLUMNS), *(f"NIS {c[4:]}" for c in nis), "lost"]
    rows = []
    for _, r in table.iterrows():
        name = f"`{r['filter']}`" + (" (RTS floor)" if r["smoother"] else "")
        rows.append([r["case"], name, *(fmt(r[c]) for c, _ in TABLE_COLUMNS),
                     *(fmt(r[c], ".3g") if np.isfinite(r[c]) else "—" for c in nis), f"{r['lost']} / {r['runs']}"])
    return md_table(headers, rows)


def improvements_md(imp: pd.DataFrame, min_pairs: int = MIN_PAIRED_RUNS) -> str:
    """Paired improvement of each case over the reference for each filter, with its 95 % interval, its mark
    (``*`` significant, ``†`` too few pairs) and whether it was assessed, by the rule of ``nespm report``."""
    keys = [k for k in CASE_METRICS if k in imp.columns]
    headers = ["case", "filter", *(f"{CASE_METRICS[k]}: improvement [95 % CI]" for k in keys), "pairs",
               "statistically"]
    rows = []
    for _, r in imp.iterrows():
        few = int(r.get("pairs_min", r["pairs"])) < min_pairs
        stat = (f"not assessed {SMALL_MARK} (fewer than {min_pairs} pairs on some track)" if few else
                "; ".join(f"{CASE_METRICS[k]} {'yes' if r.get(f'{k}_significant', False) else 'no'}" for k in keys))
        rows.append([r["case"], f"`{r['filter']}`",
                     *(fmt_imprv(r[k], r[f"{k}_lo"], r[f"{k}_hi"], r.get(f"{k}_mark", "")) for k in keys),
                     str(r["pairs"]), stat])
    return md_table(headers, rows)


def plot_cases(table: pd.DataFrame, imp: pd.DataFrame, path: Path) -> Path:
    """Left: RMS horizontal error per case and filter; right: the paired improvement of each case
    over the reference (RMS horizontal error) with its 95 % interval."""
    use_agg()
    import matplotlib.pyplot as plt

    causal = table[~table["smoother"]]
    filters = list(dict.fromkeys(causal["filter"]))
    cases = list(dict.fromkeys(causal["case"]))
    colors = filter_colors(filters)
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    width = 0.8 / max(len(filters), 1)
    x = np.arange(len(cases))
    for i, f in enumerate(filters):
        sub = causal[causal["filter"] == f].set_index("case").reindex(cases)
        a.bar(x + (i - (len(filters) - 1) / 2) * width, sub["hpe_rms"], width, color=colors[f], label=f)
        if len(imp):
            s = imp[imp["filter"] == f].set_index("case").reindex(cases[1:])
            lo, hi = s["hpe"] - s["hpe_lo"], s["hpe_hi"] - s["hpe"]
            b.errorbar(np.arange(1, len(cases)) + (i - (len(filters) - 1) / 2) * width, s["hpe"],
                       yerr=[lo.to_numpy(float), hi.to_numpy(float)], fmt="o", color=colors[f], capsize=3, label=f)
    a.set_xticks(x, cases, rotation=20, ha="right")
    a.set_ylabel("RMS horizontal position error [m]")
    a.set_title("Each case, over the runs no filter lost")
    top = float(np.nanmax(causal["hpe_rms"].to_numpy(float))) if len(causal) else 1.0
    a.set_ylim(0.0, 1.25 * top if np.isfinite(top) and top > 0 else 1.0)
    a.legend(fontsize=8, ncol=max(len(filters), 1), loc="upper center")
    b.axhline(0.0, color="0.5", lw=0.8)
    b.set_xticks(np.arange(1, len(cases)), cases[1:], rotation=20, ha="right")
    b.set_xlim(0.4, len(cases) - 0.4)
    b.set_ylabel(f"improvement over {cases[0]} [%]")
    b.set_title("RMS horizontal error: paired improvement, 95 % CI")
    fig.tight_layout()
    return save_figure(fig, path)


def write_compare_report(folders, out: str | Path, labels=None, reference: str | None = None, n_boot: int = 2000,
                         seed: int = 0) -> Path:
    """Write ``out/compare.md`` and ``out/figures/compare.png`` comparing the cases ``folders``."""
    from nespm_cli.reports.results import check_n_boot

    check_n_boot(n_boot)
    phase("reading the cases")
    cases: list[Case] = load_cases(folders, labels)
    table = case_table(cases)
    phase(f"paired improvements over the reference case ({n_boot} bootstrap resamples)")
    imp = case_improvements(cases, reference, n_boot=n_boot, seed=seed)
    from nespm_cli.reports.results import check_figures_dir

    out = Path(out)
    check_figures_dir(out).mkdir(parents=True, exist_ok=True)
    fig = plot_cases(table, imp, out / "figures" / "compare.png")
    ref = reference or cases[0].label
    lines = [
        "# nespm comparison of cases on the same realizations",
        "",
        "**Cases:** " + "; ".join(f"`{c.label}` = {c.folder} (error state {layout_text(c.manifest)}; sensors "
                                  f"{sensors_text(c.manifest)})" for c in cases) + ".",
        "",
        "The folders share the seed, tracks, runs, corruption and data (checked), so run r of track N has the "
        "same IMU and initial errors in every case and the comparisons are paired by (track, run). Each case's "
        "numbers are over the runs no filter of that case lost; `lost` counts the filter's own losses. "
        "DT = distance travelled; drift = final horizontal error per hour of track; CEP50 and R95 of the final "
        "horizontal error; NIS: mean per run (its chi-square expectation is the sensor's dimension); the RMS "
        "values over the epochs after t = 0 (docs/report.md, \"The t = 0 rule\"). "
        "Definitions: docs/report.md.",
        "",
        "## Cases",
        "",
        case_table_md(table),
        "",
        f"## What each case changes, against `{ref}`",
        "",
        "Improvement = 100 · (reference − case) / reference for the same filter, over the runs neither "
        f"lost, with its paired bootstrap 95 % interval ({n_boot} resamples): positive = the case is better. "
        "Errors after t = 0 (the first update; docs/report.md, \"The t = 0 rule\")"
        + ("" if all(has_posterior(c.metrics) for c in cases) else
           " — except that some folder has no posterior sums (older nespm): these include the t = 0 error and are "
           "diluted towards 0") + f". The rule of `nespm report`: {SIG_MARK} = the interval excludes 0 with at "
        f"least {MIN_PAIRED_RUNS} pairs on every track; {SMALL_MARK} = fewer pairs on some track, not assessed "
        "whatever the interval (the percentile bootstrap is too narrow there).",
        "",
        improvements_md(imp) if len(imp) else "(no filter is in both a case and the reference)",
        "",
        f"![compare]({fig.relative_to(out).as_posix()})",
        "",
    ]
    path = out / "compare.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


__all__ = ["case_table_md", "improvements_md", "plot_cases", "write_compare_report"]
