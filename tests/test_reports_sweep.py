"""Tests of nespm_cli.reports.sweep: per-value tables (eqs 50-51), bootstrap and Wilson
intervals, improvement over a baseline with paired intervals, divergences, axes, report.md."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from nespm_cli.reports import dispatch, markdown, stats
from nespm_cli.reports import mc as report
from nespm_cli.errors import NespmError
from nespm_cli.experiments.metrics import nees_band
from nespm_cli.reports.sweep import (
    default_baseline,
    filter_bootstrap,
    improvement_table,
    load_sweep,
    sweep_table,
    use_log_x,
    use_log_y,
    wilson_interval,
    write_sweep_report,
)

TRACKS = (5, 6)
FILTERS = ("ekf", "ukf", "ukf-nespm")
VALUES = (0.01, 1.0, 30.0)
RUNS = 20
BASE = {"ekf": 0.10, "ukf": 0.08, "ukf-nespm": 0.07}


def make_sweep(
    values=VALUES,
    filters=FILTERS,
    runs: int = RUNS,
    diverged: dict[tuple[float, str], set[tuple[int, int]]] | None = None,
    copy_of: dict[str, str] | None = None,
    param: str = "misalignment-deg",
) -> pd.DataFrame:
    """Sweep metrics with sse_vel = n * v**2, sse_att = n * (0.1 v)**2 + ..., n = 300 + 7 run + track.

    Per-run v = BASE[filter] * (1 + log10(value) / 3 + 0.3 sin(run + track) + 0.05 N(0, 1)).
    ``diverged[(value, filter)]`` lists the (track, run) pairs that diverged (NaN sums);
    ``copy_of[f] = g`` makes filter f a row-by-row copy of filter g.
    """
    rng = np.random.default_rng(3)
    diverged = diverged or {}
    rows = []
    for v in values:
        for f in filters:
            src = (copy_of or {}).get(f, f)
            for track in TRACKS:
                for run in range(runs):
                    n = 300 + 7 * run + track
                    z = rng.standard_normal(2)
                    vel = BASE.get(src, 0.09) * (1 + math.log10(v) / 3 + 0.3 * math.sin(run + track) + 0.05 * z[0])
                    vel = abs(vel) + 0.01
                    att = 0.1 * vel * (1 + 0.1 * z[1])
                    bad = (track, run) in diverged.get((v, f), set())
                    rows.append(
                        {
                            "param": param, "value": float(v), "track": track, "filter": f, "run": run,
                            "scenario": "nominal", "schedule": "constant", "seed": 7,
                            "vrmse": math.nan if bad else vel, "mrmse": math.nan if bad else att,
                            "sse_vel": math.nan if bad else n * vel**2,
                            "sse_att": math.nan if bad else n * att**2,
                            "n_samples": n, "max_vel_err": 2 * vel, "max_att_err": 2 * att,
                            "nees": math.nan if bad else 6.0 + 10 * vel, "diverged": bad, "seconds": 0.1,
                        }
                    )
    m = pd.DataFrame(rows)
    for f, g in (copy_of or {}).items():  # exact copies of g's rows (same realizations)
        for col in ("vrmse", "mrmse", "sse_vel", "sse_att", "nees", "diverged", "max_vel_err", "max_att_err"):
            m.loc[m["filter"] == f, col] = m.loc[m["filter"] == g, col].to_numpy()
    return m


def hand(m: pd.DataFrame, value: float, filt: str, col: str = "sse_vel") -> float:
    """Eqs 50-51 by hand: sqrt(mean over tracks of sum(sse) / sum(n)), non-diverged rows."""
    ratios = []
    for tr in sorted(m["track"].unique()):
        d = m[(m["value"] == value) & (m["track"] == tr) & (m["filter"] == filt) & ~m["diverged"]]
        ratios.append(d[col].sum() / d["n_samples"].sum() if len(d) else math.nan)
    return float(np.sqrt(np.mean(ratios)))


def row(t: pd.DataFrame, value: float, filt: str) -> pd.Series:
    return t[(t["value"] == value) & (t["filter"] == filt)].iloc[0]


def write_folder(path: Path, m: pd.DataFrame, manifest: dict | None = None) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    m.to_parquet(path / "metrics.parquet", index=False)
    if manifest is not None:
        (path / "manifest.json").write_text(json.dumps(manifest))
    return path


# ----------------------------------------------------------------------------- tables


def test_table_vrmse_mrmse_match_eq_50_51() -> None:
    m = make_sweep()
    t = sweep_table(m, n_boot=0)
    assert len(t) == len(VALUES) * len(FILTERS)
    assert list(t["value"].unique()) == list(VALUES)
    for v in VALUES:
        for f in FILTERS:
            r = row(t, v, f)
            assert r["vrmse"] == pytest.approx(hand(m, v, f), rel=0, abs=1e-12)
            assert r["mrmse"] == pytest.approx(hand(m, v, f, "sse_att"), rel=0, abs=1e-12)
            nees = m[(m["value"] == v) & (m["filter"] == f)]["nees"].mean()
            assert r["nees"] == pytest.approx(nees, abs=1e-12)
            assert (r["diverged"], r["runs"], r["div_rate"]) == (0, 2 * RUNS, 0.0)


def test_filter_bootstrap_matches_naive_loop_and_contains_point() -> None:
    m = make_sweep()
    sub = m[m["value"] == 1.0]
    n_boot, seed = 50, 4
    boot = filter_bootstrap(sub, "ukf", n_boot=n_boot, seed=seed)
    idx = {}
    for tr in TRACKS:
        rng = np.random.default_rng([seed, tr])
        idx[tr] = rng.integers(0, RUNS, size=(n_boot, RUNS))
    for b in (0, 17, 49):
        ratios, nees = [], []
        for tr in TRACKS:
            d = sub[(sub["track"] == tr) & (sub["filter"] == "ukf")].sort_values("run")
            pick = d.iloc[idx[tr][b]]
            ratios.append(pick["sse_vel"].sum() / pick["n_samples"].sum())
            nees.append(pick["nees"].to_numpy())
        assert boot["vrmse"][b] == pytest.approx(np.sqrt(np.mean(ratios)), abs=1e-12)
        assert boot["nees"][b] == pytest.approx(np.concatenate(nees).mean(), abs=1e-12)
    t = sweep_table(m, n_boot=500)
    for key in ("vrmse", "mrmse", "nees"):
        assert (t[f"{key}_lo"] <= t[key]).all() and (t[key] <= t[f"{key}_hi"]).all()
        assert (t[f"{key}_hi"] - t[f"{key}_lo"] > 0).all()


def test_improvement_formula_and_paired_ci() -> None:
    m = make_sweep()
    imp = improvement_table(m, n_boot=800)
    assert imp.attrs["baseline"] == "ekf"
    assert len(imp) == len(VALUES) * 2 and "ekf" not in set(imp["filter"])
    for v in VALUES:
        for f in ("ukf", "ukf-nespm"):
            r = row(imp, v, f)
            for key, col in (("vrmse", "sse_vel"), ("mrmse", "sse_att")):
                b, x = hand(m, v, "ekf", col), hand(m, v, f, col)
                assert r[f"{key}_imprv"] == pytest.approx(100 * (b - x) / b, rel=0, abs=1e-12)
                assert r[f"{key}_ci_lo"] <= r[f"{key}_imprv"] <= r[f"{key}_ci_hi"]
    # ukf-nespm (0.07) is clearly better than ekf (0.10): positive and excluding 0
    assert (imp.loc[imp["filter"] == "ukf-nespm", "vrmse_imprv"] > 20).all()
    assert imp.loc[imp["filter"] == "ukf-nespm", "vrmse_ci_excludes_0"].all()


def test_paired_interval_uses_the_same_resample() -> None:
    """A filter equal to the baseline times 0.9 in every run: the paired interval collapses
    to the point (10 %), an unpaired one would not."""
    m = make_sweep(copy_of={"ukf": "ekf"})
    sel = m["filter"] == "ukf"
    for col in ("sse_vel", "sse_att"):
        m.loc[sel, col] *= 0.81
    imp = improvement_table(m, n_boot=300)
    for v in VALUES:
        r = row(imp, v, "ukf")
        assert r["vrmse_imprv"] == pytest.approx(10.0, abs=1e-10)
        assert r["vrmse_ci_lo"] == pytest.approx(10.0, abs=1e-9)
        assert r["vrmse_ci_hi"] == pytest.approx(10.0, abs=1e-9)


def section(text: str, name: str) -> str:
    """The body of the report section whose heading starts with ``## name`` (up to the next section)."""
    return text.split(f"## {name}")[1].split("\n## ")[0]


def test_filter_identical_to_baseline_interval_contains_zero_no_star(tmp_path: Path) -> None:
    """A copy of the baseline: improvement 0, an interval containing 0, no star; a better filter starred."""
    m = make_sweep(copy_of={"ukf-nespm": "ekf"})
    imp = improvement_table(m, n_boot=300)
    same = imp[imp["filter"] == "ukf-nespm"]
    for key in ("vrmse", "mrmse"):
        assert np.allclose(same[f"{key}_imprv"], 0.0, atol=1e-12)
        assert ((same[f"{key}_ci_lo"] <= 0) & (same[f"{key}_ci_hi"] >= 0)).all()
        assert not same[f"{key}_ci_excludes_0"].any()
    write_folder(tmp_path, m)
    text = write_sweep_report(tmp_path, n_boot=300).read_text()
    imp_md = section(text, "Improvement over")
    rows = [ln for ln in imp_md.splitlines() if ln.startswith("| ") and not ln.startswith(("| initial", "| ---"))]
    assert len(rows) == 2 * len(VALUES)
    for ln in rows:  # columns: value | ukf | ukf-nespm
        cells = [c.strip() for c in ln.strip("|").split("|")]
        assert "*" not in cells[2]
        assert "*" in cells[1]  # ukf (0.08 vs 0.10) is significantly better


def test_default_baseline() -> None:
    m = make_sweep(values=(1.0,), runs=3)
    assert default_baseline(m) == "ekf"
    assert default_baseline(m, "ukf") == "ukf"
    assert default_baseline(m[m["filter"] != "ekf"]) == "ukf"
    with pytest.raises(NespmError, match="unknown filter"):
        default_baseline(m, "anukf")


# ----------------------------------------------------------------------------- divergences


def test_divergence_rate_counts_and_excluded_from_errors() -> None:
    div = {(1.0, "ukf"): {(5, 0), (5, 3), (6, 19)}, (30.0, "ekf"): {(6, 2)}}
    m = make_sweep(diverged=div)
    t = sweep_table(m, n_boot=200)
    r = row(t, 1.0, "ukf")
    assert (r["diverged"], r["runs"]) == (3, 40)
    assert r["div_rate"] == pytest.approx(3 / 40, abs=1e-15)
    assert r["div_rate_lo"] < 3 / 40 < r["div_rate_hi"]
    assert r["vrmse"] == pytest.approx(hand(m, 1.0, "ukf"), abs=1e-12)
    assert np.isfinite(r["vrmse_lo"])
    assert row(t, 30.0, "ekf")["div_rate"] == pytest.approx(1 / 40)
    assert row(t, 0.01, "ukf")["div_rate"] == 0.0
    assert t["diverged"].sum() == 4


def test_wilson_interval_values() -> None:
    z = 1.959963984540054
    lo, hi = wilson_interval(0, 20)
    assert lo == 0.0 and hi == pytest.approx(z**2 / (20 + z**2), abs=1e-12)
    lo, hi = wilson_interval(20, 20)
    assert hi == 1.0 and lo == pytest.approx(20 / (20 + z**2), abs=1e-12)
    lo, hi = wilson_interval(5, 10)
    assert lo == pytest.approx(1 - hi, abs=1e-12) and lo < 0.5 < hi
    assert all(math.isnan(x) for x in wilson_interval(0, 0))


def test_all_diverged_value_gives_nan_and_rate_one(tmp_path: Path) -> None:
    """A swept value where every run diverged gives NaN errors, a divergence rate of 1 and dashes in the report."""
    every = {(t, r) for t in TRACKS for r in range(RUNS)}
    div = {(30.0, f): every for f in FILTERS}
    div[(1.0, "ukf")] = every  # one filter lost at another value
    m = make_sweep(diverged=div)
    t = sweep_table(m, n_boot=100)
    for f in FILTERS:
        r = row(t, 30.0, f)
        assert math.isnan(r["vrmse"]) and math.isnan(r["mrmse"]) and math.isnan(r["nees"])
        assert math.isnan(r["vrmse_lo"]) and math.isnan(r["vrmse_hi"])
        assert r["div_rate"] == 1.0 and r["div_rate_hi"] == 1.0 and r["runs"] == 40
    assert math.isnan(row(t, 1.0, "ukf")["vrmse"]) and row(t, 1.0, "ukf")["div_rate"] == 1.0
    assert np.isfinite(row(t, 1.0, "ekf")["vrmse"])
    imp = improvement_table(m, n_boot=100)
    assert imp.loc[imp["value"] == 30.0, "vrmse_imprv"].isna().all()
    assert not imp.loc[imp["value"] == 30.0, "vrmse_ci_excludes_0"].any()
    write_folder(tmp_path, m)
    text = write_sweep_report(tmp_path, n_boot=100).read_text()
    lo = wilson_interval(40, 40)[0]
    assert lo == pytest.approx(40 / (40 + 1.959963984540054**2)) and f"1.00 [{lo:.2f}, 1.00] (40/40)" in text
    assert "| 30 | — | — |" in text  # improvement cells of an all-diverged value
    assert "value 30, `ekf`: every run diverged" in text
    assert len(list((tmp_path / "figures").glob("sweep_*.png"))) == 5


# ----------------------------------------------------------------------------- axes


def test_log_axes_choice() -> None:
    assert use_log_x([0.01, 0.1, 1, 3, 10, 30])
    assert use_log_x([0.01, 30])
    assert not use_log_x([1, 3, 10])
    assert not use_log_x([1, 10, 100])  # exactly 100: linear
    assert not use_log_x([0.0, 1.0, 1000.0])  # non-positive value
    assert not use_log_x([5.0])
    assert use_log_y([0.03, 0.8])
    assert not use_log_y([0.1, 0.9])
    assert not use_log_y([np.nan, 0.1, 0.5])


# ----------------------------------------------------------------------------- report.md


MANIFEST = {
    "options": {"tracks": [5, 6], "runs": RUNS, "scenario": "nominal", "schedule": "constant",
                "dvl": "synthetic", "imu": "synthetic",
                "sweep": {"param": "misalignment-deg", "values": list(VALUES)}},
    "seed": 7, "data_dir": "/data/snapir", "wall_seconds": 123.4,
}


def test_write_sweep_report(tmp_path: Path) -> None:
    """The whole sweep report: sections in order, a table row per value, run line, NEES band, five figures."""
    m = make_sweep()
    write_folder(tmp_path, m, MANIFEST)
    path = write_sweep_report(tmp_path, n_boot=300)
    assert path == tmp_path / "report.md"
    text = path.read_text()
    assert "initial misalignment std per axis [deg]" in text
    assert "| initial misalignment std per axis [deg] | ekf | ukf | ukf-nespm |" in text
    assert "| initial misalignment std per axis [deg] | ukf | ukf-nespm |" in text
    assert text.index("## Verdict") < text.index("## Caveats") < text.index("## Track-averaged VRMSE")
    assert "## Definitions" not in text and "docs/report.md" in text
    verdict, pairwise = section(text, "Verdict"), section(text, "Pairwise comparisons")
    tables = text.split("## Track-averaged VRMSE")[1].split("## Pairwise comparisons")[0]
    for v in ("0.01", "1", "30"):
        # VRMSE, MRMSE, NEES, divergence, 2 improvement tables; the verdict: velocity and attitude RMSE,
        # ANEES; the pairwise comparisons: VRMSE, MRMSE
        assert sum(ln.startswith(f"| {v} |") for ln in tables.splitlines()) == 6
        assert sum(ln.startswith(f"| {v} |") for ln in verdict.splitlines()) == 3
        assert sum(ln.startswith(f"| {v} | VRMSE |") or ln.startswith(f"| {v} | MRMSE |")
                   for ln in pairwise.splitlines()) == 2
    r = row(sweep_table(m, n_boot=0), 1.0, "ukf")
    assert f"{r['vrmse']:.4g} [" in text
    for s in ("seed 7", "data dir /data/snapir", "wall time 123.4 s", "tracks 5, 6",
              "runs per track 20", "filters ekf, ukf, ukf-nespm", "DVL synthetic", "baseline `ekf`"):
        assert s in text
    lo, hi = nees_band(6, 2 * RUNS)
    assert f"[{lo:.2f}, {hi:.2f}]" in text and "overconfident" in text
    names = {p.name for p in (tmp_path / "figures").glob("*.png")}
    assert names == {"sweep_vrmse.png", "sweep_mrmse.png", "sweep_nees.png",
                     "sweep_divergence.png", "sweep_improvement.png"}
    for n in names:
        assert (tmp_path / "figures" / n).stat().st_size > 5_000
        assert f"(figures/{n})" in text
    # option baseline
    text2 = write_sweep_report(tmp_path, baseline="ukf", n_boot=50).read_text()
    assert "baseline `ukf`" in text2 and "| initial misalignment std per axis [deg] | ekf | ukf-nespm |" in text2


def test_write_report_dispatches_to_sweep(tmp_path: Path) -> None:
    """nespm report writes the sweep report for a sweep folder and the ordinary report for an mc folder."""
    m = make_sweep(values=(0.5, 2.0), runs=6, param="dvl-noise")
    write_folder(tmp_path, m)
    path = dispatch.write_report(tmp_path, "ukf", n_boot=40)
    text = path.read_text()
    assert text.startswith("# nespm sweep report: dvl-noise")
    assert "DVL noise std [m/s]" in text and "baseline `ukf`" in text
    assert (tmp_path / "figures" / "sweep_vrmse.png").is_file()
    # an ordinary mc folder still gets the ordinary report
    mc = tmp_path / "mc"
    write_folder(mc, m[m["value"] == 0.5].drop(columns=["param", "value"]))
    assert dispatch.write_report(mc, n_boot=20).read_text().startswith("# nespm Monte Carlo report")


def test_load_sweep_errors(tmp_path: Path) -> None:
    with pytest.raises(NespmError, match="not found"):
        load_sweep(tmp_path / "missing")
    with pytest.raises(NespmError, match="not found"):
        load_sweep(tmp_path)
    m = make_sweep(values=(1.0, 2.0), runs=3)
    m.loc[m["value"] == 2.0, "param"] = "vel-std"
    write_folder(tmp_path, m)
    with pytest.raises(NespmError, match="one swept parameter"):
        load_sweep(tmp_path)
    m = make_sweep(values=(1.0,), runs=3)
    write_folder(tmp_path, pd.concat([m, m.iloc[:1]]))
    with pytest.raises(NespmError, match="duplicate row"):
        load_sweep(tmp_path)


# ----------------------------------------------------------------------------- one run set, table = figure


def divergent_sweep() -> pd.DataFrame:
    """At 30 the baseline loses many runs, ukf a few, ukf-nespm one: the pairs with ekf differ
    between ukf and ukf-nespm (the README's 30 deg case)."""
    div = {
        (30.0, "ekf"): {(5, r) for r in range(0, 8)} | {(6, r) for r in range(0, 5)},
        (30.0, "ukf"): {(5, 10), (6, 11), (6, 12)},
        (30.0, "ukf-nespm"): {(5, 3)},
    }
    return make_sweep(diverged=div)


def test_improvement_table_and_figure_show_the_same_numbers(tmp_path: Path, monkeypatch) -> None:
    """The improvement figure draws exactly the improvement table's numbers (paired over the runs both filters kept)."""
    from nespm_cli.reports import sweep as sr
    from nespm_cli.reports import sweep_figures

    m = divergent_sweep()
    imp = improvement_table(m, n_boot=300)
    plotted: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]] = {}
    original = sweep_figures.save_figure

    def capture(fig, path, *a, **k):
        if Path(path).stem == "sweep_improvement":
            for ax, key in zip(fig.axes, ("vrmse", "mrmse")):
                plotted[key] = {ln.get_label().split(" vs ")[0]: (np.asarray(ln.get_xdata(), float),
                                                                   np.asarray(ln.get_ydata(), float))
                                for ln in ax.get_lines() if " vs " in str(ln.get_label())}
        return original(fig, path, *a, **k)

    monkeypatch.setattr(sweep_figures, "save_figure", capture)  # where the figure is saved
    table = sweep_table(m, n_boot=0)
    sr.plot_sweep_figures(m, {}, table, imp, tmp_path / "figures")
    text = sr.render_sweep_report(m, {}, table, imp, [], tmp_path, 300, 0)
    imp_md = section(text, "Improvement over")
    tables = {"vrmse": imp_md.split("**VRMSE**")[1].split("**MRMSE**")[0], "mrmse": imp_md.split("**MRMSE**")[1]}
    for key in ("vrmse", "mrmse"):
        assert set(plotted[key]) == {"ukf", "ukf-nespm"}
        for col, f in enumerate(("ukf", "ukf-nespm"), start=1):
            pts = sr.improvement_points(imp, key, f)
            x, y = plotted[key][f]
            np.testing.assert_array_equal(x, pts["value"].to_numpy())
            np.testing.assert_array_equal(y, pts["imprv"].to_numpy())  # the figure draws the table's numbers
            for v in VALUES:  # each is the paired improvement over ekf on the runs both kept
                sub = m[m["value"] == v]
                want = stats.paired_improvement(sub, "ekf", f)[key]
                assert pts.set_index("value").loc[v, "imprv"] == pytest.approx(want, abs=1e-12)
                cell = next(ln for ln in tables[key].splitlines() if ln.startswith(f"| {v:g} |"))
                cells = [c.strip() for c in cell.strip("|").split("|")]
                r = pts.set_index("value").loc[v]
                assert cells[col] == markdown.fmt_imprv(r["imprv"], r["ci_lo"], r["ci_hi"], r["mark"])
    # the pairs with ekf at 30: 27 on track 5 ... differ between the two filters
    sub = m[m["value"] == 30.0]
    assert stats.paired_run_counts(sub, "ekf", "ukf") != stats.paired_run_counts(sub, "ekf", "ukf-nespm")


def test_sweep_summary_compares_filters_head_to_head(tmp_path: Path) -> None:
    """The pairwise-comparison and verdict rows of a sweep report carry compare_filters' own numbers."""
    m = divergent_sweep()
    write_folder(tmp_path, m, MANIFEST)
    text = write_sweep_report(tmp_path, n_boot=300).read_text()
    summ = section(text, "Pairwise comparisons")
    line30 = next(ln for ln in summ.splitlines() if ln.startswith("| 30 | VRMSE |"))
    sub = m[m["value"] == 30.0].drop(columns=["param", "value"])
    c = report.compare_filters(sub, n_boot=300).set_index(["metric", "other"])
    best = c.loc["vrmse"]["best"].iloc[0]
    assert best == "ukf-nespm"  # BASE 0.07 < 0.08 < 0.10
    r = c.loc[("vrmse", "ukf")]
    assert r["imprv"] == pytest.approx(stats.paired_improvement(sub, "ukf", "ukf-nespm")["vrmse"], abs=1e-12)
    assert f"vs `ukf` {markdown.fmt_imprv(r['imprv'], r['ci_lo'], r['ci_hi'], '*' if r['significant'] else '')} meaningful" in line30
    assert "vs `ekf`" in line30 and "`ukf-nespm` is best" in line30
    # the verdict of value 30: the best against its runner-up ukf, the same numbers as compare_filters
    v30 = next(ln for ln in section(text, "Verdict").splitlines() if ln.startswith("| 30 | velocity RMSE"))
    cells = [c.strip() for c in v30.strip().strip("|").split("|")]
    e = c.loc[("vrmse", "ukf")]
    assert cells[2].startswith("`ukf-nespm` ") and cells[3].startswith("`ukf` ")
    assert cells[4] == markdown.fmt_imprv(e["imprv"], e["ci_lo"], e["ci_hi"], "*" if e["significant"] else "")
    from nespm_cli.reports.markdown import REPORT_DOCS

    defs = " ".join(REPORT_DOCS.read_text().split())
    assert "need not rank two filters alike" in defs and "improvement_points" in defs


def test_sweep_small_sample_not_starred(tmp_path: Path) -> None:
    """With 5 paired runs an interval excluding 0 is not starred, and the caveat names every value and track once."""
    m = make_sweep(values=(1.0, 30.0), runs=5)
    imp = improvement_table(m, n_boot=200)
    nespm = imp[imp["filter"] == "ukf-nespm"]
    assert (nespm["pairs_min"] == 5).all()
    assert nespm["vrmse_ci_excludes_0"].all() and not nespm["vrmse_significant"].any()
    write_folder(tmp_path, m)
    text = write_sweep_report(tmp_path, n_boot=200).read_text()
    rows = [ln for ln in section(text, "Improvement over").splitlines() if ln.startswith(("| 1 |", "| 30 |"))]
    assert rows and all("†" in ln and "*" not in ln for ln in rows)
    summary = section(text, "Pairwise comparisons")
    row30 = next(ln for ln in summary.splitlines() if ln.startswith("| 30 | VRMSE |"))
    assert "not assessed (too few paired runs)" in row30 and "† too few paired runs" in row30
    assert "*" not in row30
    cav = section(text, "Caveats")  # said once, naming every value and track
    assert text.count("distinct resamples") == 1 and "value 1, track 5: 5, track 6: 5" in cav
