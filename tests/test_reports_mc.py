"""Tests of the Monte Carlo report (nespm_cli.reports.mc and the modules it re-exports): eq 50-51 tables,
improvement, paired bootstrap, the verdict-first report.md, figures."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from nespm_cli.errors import NespmError
from nespm_cli.experiments.metrics import nees_band
from nespm_cli.reports.dispatch import write_report
from nespm_cli.reports.markdown import decimals, fmt_ci, fmt_imprv, fmt_pct
from nespm_cli.reports.mc import (
    compare_filters,
    default_reference,
    filter_table,
    horizontal_table,
    nees_consistency,
    render_report,
    track_table,
)
from nespm_cli.reports.published import PUBLISHED, published_tables
from nespm_cli.reports.results import load_results
from nespm_cli.reports.stats import MIN_PAIRED_RUNS, PRACTICAL_PCT, paired_bootstrap, paired_improvement

TRACKS = (5, 6)


def make_metrics(
    vel: dict[tuple[int, str], np.ndarray],
    att: dict[tuple[int, str], np.ndarray] | None = None,
    scenario: str = "nominal",
) -> pd.DataFrame:
    """metrics.parquet rows with sse_vel = n * v**2, sse_att = n * a**2, n_samples = 300 + 7 * run + track."""
    rows = []
    for (track, filt), v in vel.items():
        a = att[(track, filt)] if att is not None else 0.1 * np.asarray(v)
        for run, (vi, ai) in enumerate(zip(v, a)):
            n = 300 + 7 * run + track
            rows.append(
                {
                    "track": track, "filter": filt, "run": run, "scenario": scenario,
                    "schedule": "constant", "seed": 7, "vrmse": float(vi), "mrmse": float(ai),
                    "sse_vel": n * vi**2, "sse_att": n * ai**2, "n_samples": n,
                    "max_vel_err": 2 * vi, "max_att_err": 2 * ai, "nees": 6.0 + vi,
                    "diverged": False, "seconds": 0.1,
                }
            )
    return pd.DataFrame(rows)


def noisy_metrics(
    runs: int, bases: dict[str, float], noise: float = 0.01, seed: int = 1
) -> pd.DataFrame:
    """2 tracks × len(bases) filters × runs, per-run v = base (+0.01 on track 6) + N(0, noise)."""
    rng = np.random.default_rng(seed)
    vel = {
        (tr, f): b + 0.01 * (tr == 6) + noise * rng.standard_normal(runs)
        for tr in TRACKS
        for f, b in bases.items()
    }
    return make_metrics(vel)


def hand_vrmse(m: pd.DataFrame, filt: str, col: str = "sse_vel") -> float:
    """Eq 50-51 by hand: sqrt(mean over tracks of sum(sse)/sum(n)), non-diverged rows."""
    ms = []
    for tr in sorted(m["track"].unique()):
        d = m[(m["track"] == tr) & (m["filter"] == filt) & ~m["diverged"]]
        ms.append(d[col].sum() / d["n_samples"].sum())
    return float(np.sqrt(np.mean(ms)))


@pytest.fixture
def three() -> pd.DataFrame:
    """2 tracks × 3 filters × 20 runs with distinct, deterministic per-run errors."""
    r = np.arange(20)
    vel = {}
    for tr in TRACKS:
        vel[(tr, "ukf")] = 0.10 + 0.002 * r + 0.01 * (tr == 6)
        vel[(tr, "anekf")] = 0.09 + 0.001 * (r % 5) + 0.02 * (tr == 6)
        vel[(tr, "anukf")] = 0.08 + 0.0015 * ((3 * r) % 7)
    return make_metrics(vel)


# ----------------------------------------------------------------------------- point values


def test_vrmse_mrmse_match_eq_50_51(three: pd.DataFrame) -> None:
    table = filter_table(three, "anukf", n_boot=0)
    for row in table.itertuples():
        assert row.vrmse == pytest.approx(hand_vrmse(three, row.filter), abs=1e-12)
        assert row.mrmse == pytest.approx(hand_vrmse(three, row.filter, "sse_att"), abs=1e-12)
    # eq 50 weights by n_samples: differs from the mean of the per-run vrmse column
    ukf = three[three["filter"] == "ukf"]
    naive = np.sqrt(np.mean([np.mean(g["vrmse"] ** 2) for _, g in ukf.groupby("track")]))
    assert abs(table.loc[0, "vrmse"] - naive) > 1e-6


def test_improvement_formula(three: pd.DataFrame) -> None:
    table = filter_table(three, "anukf", n_boot=0).set_index("filter")
    ref_v, ref_a = hand_vrmse(three, "anukf"), hand_vrmse(three, "anukf", "sse_att")
    for f in ("ukf", "anekf"):
        v, a = hand_vrmse(three, f), hand_vrmse(three, f, "sse_att")
        assert table.loc[f, "vrmse_imprv"] == pytest.approx(100 * (v - ref_v) / v, abs=1e-12)
        assert table.loc[f, "mrmse_imprv"] == pytest.approx(100 * (a - ref_a) / a, abs=1e-12)
    assert np.isnan(table.loc["anukf", "vrmse_imprv"])
    assert table.loc["anukf", "is_reference"]
    assert table.attrs["reference"] == "anukf"


def test_table_I_of_anukf_reproduced() -> None:
    pub = PUBLISHED["anukf-table1"]["values"]
    vel = {(tr, f): np.full(20, pub[f]["vrmse"]) for tr in TRACKS for f in ("ukf", "anekf", "anukf")}
    att = {(tr, f): np.full(20, pub[f]["mrmse"]) for tr in TRACKS for f in ("ukf", "anekf", "anukf")}
    table = filter_table(make_metrics(vel, att), "anukf", n_boot=0).set_index("filter")
    assert table.loc["ukf", "vrmse"] == pytest.approx(0.1172, abs=1e-12)
    assert table.loc["anukf", "vrmse"] == pytest.approx(0.0922, abs=1e-12)
    # the paper's "ANUKF Imprv." column: 21.3 %, 8.2 % (VRMSE) and 5.4 %, 32.1 % (MRMSE)
    assert fmt_pct(table.loc["ukf", "vrmse_imprv"]) == "21.3 %"
    assert fmt_pct(table.loc["anekf", "vrmse_imprv"]) == "8.2 %"
    assert fmt_pct(table.loc["ukf", "mrmse_imprv"]) == "5.4 %"
    assert fmt_pct(table.loc["anekf", "mrmse_imprv"]) == "32.1 %"


def test_diverged_run_excluded_and_counted(three: pd.DataFrame) -> None:
    m = three.copy()
    hit = (m["track"] == 6) & (m["filter"] == "anekf") & (m["run"] == 3)
    m.loc[hit, ["diverged"]] = True
    m.loc[hit, ["sse_vel", "sse_att", "nees"]] = np.nan
    table = filter_table(m, "anukf", n_boot=200).set_index("filter")
    assert table.loc["anekf", "diverged"] == 1
    assert table.loc["anekf", "runs"] == 40
    assert table.loc["ukf", "diverged"] == 0
    assert np.isfinite(table.loc["anekf", "vrmse"])
    assert table.loc["anekf", "vrmse"] == pytest.approx(hand_vrmse(m, "anekf"), abs=1e-12)
    assert table.loc["anekf", "vrmse"] != pytest.approx(hand_vrmse(three, "anekf"), abs=1e-9)
    assert np.isfinite(table.loc["anekf", "vrmse_ci_lo"])
    tt = track_table(m).set_index(["track", "filter"])
    assert tt.loc[(6, "anekf"), "diverged"] == 1 and tt.loc[(6, "anekf"), "runs"] == 20
    assert tt.loc[(5, "anekf"), "diverged"] == 0


def test_all_runs_diverged_on_a_track_gives_nan() -> None:
    m = noisy_metrics(10, {"ukf": 0.12, "anukf": 0.09})
    hit = (m["track"] == 5) & (m["filter"] == "ukf")
    m.loc[hit, "diverged"] = True
    m.loc[hit, ["sse_vel", "sse_att"]] = np.nan
    table = filter_table(m, "anukf", n_boot=50).set_index("filter")
    assert np.isnan(table.loc["ukf", "vrmse"]) and np.isnan(table.loc["ukf", "vrmse_ci_lo"])
    assert table.loc["ukf", "diverged"] == 10


def test_track_table_values(three: pd.DataFrame) -> None:
    tt = track_table(three)
    assert list(tt["track"]) == [5, 5, 5, 6, 6, 6]
    assert list(tt["filter"]) == ["ukf", "anekf", "anukf"] * 2
    for r in tt.itertuples():
        d = three[(three["track"] == r.track) & (three["filter"] == r.filter)]
        assert r.vrmse == pytest.approx(np.sqrt(d["sse_vel"].sum() / d["n_samples"].sum()), abs=1e-12)
        assert r.nees == pytest.approx(d["nees"].mean(), abs=1e-12)
        assert r.runs == 20 and r.diverged == 0


def test_default_reference() -> None:
    m = noisy_metrics(3, {"ekf": 0.1, "ukf-nespm": 0.08, "ukf": 0.09})
    assert default_reference(m) == "ukf-nespm"
    m2 = noisy_metrics(3, {"ekf": 0.1, "ukf": 0.09})
    assert default_reference(m2) == "ukf"
    assert filter_table(m2, None, n_boot=0).attrs["reference"] == "ukf"
    with pytest.raises(NespmError, match="--baseline: unknown filter 'anukf'") as err:
        filter_table(m2, "anukf")
    assert "\n" not in str(err.value)


# ----------------------------------------------------------------------------- bootstrap


def naive_bootstrap(m: pd.DataFrame, row: str, ref: str, n_boot: int, seed: int) -> np.ndarray:
    """Loop over resamples with the same draws as the implementation (reference check)."""
    per_track = []
    for tr in sorted(m["track"].unique()):
        rng = np.random.default_rng([seed, int(tr)])
        a = m[(m["track"] == tr) & (m["filter"] == row)].set_index("run").sort_index()
        b = m[(m["track"] == tr) & (m["filter"] == ref)].set_index("run").sort_index()
        ok = ~(a["diverged"].to_numpy() | b["diverged"].to_numpy())
        a, b = a[ok], b[ok]
        idx = rng.integers(0, len(a), size=(n_boot, len(a)))
        per_track.append(
            [
                (
                    a["sse_vel"].to_numpy()[i].sum() / a["n_samples"].to_numpy()[i].sum(),
                    b["sse_vel"].to_numpy()[i].sum() / b["n_samples"].to_numpy()[i].sum(),
                )
                for i in idx
            ]
        )
    arr = np.array(per_track)  # (tracks, n_boot, 2)
    va, vb = np.sqrt(arr[..., 0].mean(axis=0)), np.sqrt(arr[..., 1].mean(axis=0))
    return 100 * (va - vb) / va


def test_bootstrap_matches_naive_loop(three: pd.DataFrame) -> None:
    m = three.copy()
    m.loc[(m["track"] == 5) & (m["filter"] == "ukf") & (m["run"] == 2), "diverged"] = True
    boot = paired_bootstrap(m, "ukf", "anukf", n_boot=300, seed=4)
    np.testing.assert_allclose(boot["vrmse"], naive_bootstrap(m, "ukf", "anukf", 300, 4), atol=1e-10)


def test_bootstrap_ci_contains_point_and_shrinks() -> None:
    bases = {"ukf": 0.12, "anukf": 0.09}
    widths = []
    for runs in (20, 200):
        t = filter_table(noisy_metrics(runs, bases, noise=0.02), "anukf", n_boot=2000).set_index("filter")
        lo, hi, point = t.loc["ukf", ["vrmse_ci_lo", "vrmse_ci_hi", "vrmse_imprv"]]
        assert lo < point < hi
        assert t.loc["ukf", "vrmse_ci_excludes_0"]
        widths.append(hi - lo)
    assert widths[1] < 0.6 * widths[0]


def test_bootstrap_ci_includes_zero_for_equal_filters() -> None:
    t = filter_table(noisy_metrics(20, {"ukf": 0.1, "anukf": 0.1}, noise=0.03), "anukf", n_boot=2000)
    row = t.set_index("filter").loc["ukf"]
    assert row["vrmse_ci_lo"] < 0 < row["vrmse_ci_hi"]
    assert not row["vrmse_ci_excludes_0"]


def test_bootstrap_deterministic_for_seed() -> None:
    m = noisy_metrics(20, {"ukf": 0.12, "anekf": 0.1, "anukf": 0.09})
    cols = ["vrmse_ci_lo", "vrmse_ci_hi", "mrmse_ci_lo", "mrmse_ci_hi"]
    a = filter_table(m, "anukf", n_boot=500, seed=3)[cols].to_numpy()
    b = filter_table(m, "anukf", n_boot=500, seed=3)[cols].to_numpy()
    c = filter_table(m, "anukf", n_boot=500, seed=4)[cols].to_numpy()
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a[:2], c[:2])


# ----------------------------------------------------------------------------- report + figures


def make_epochs(tracks: tuple[int, ...], filters: tuple[str, ...], n: int = 300) -> pd.DataFrame:
    """epochs.parquet rows: a curved path, errors growing in a 20 s DVL outage from t = 180 s."""
    rows = []
    t = np.arange(n, dtype=float)
    outage = (t >= 180) & (t < 200)
    for tr in tracks:
        east, north = 200 * np.sin(t / 80 + tr), 1.5 * t + 30 * np.cos(t / 50)
        for k, f in enumerate(filters):
            ve = 0.05 * (k + 1) * (1 + 0.3 * np.sin(t / 9)) + np.where(outage, 0.01 * (t - 180), 0)
            ae = 0.005 * (k + 1) * (1 + 0.2 * np.cos(t / 13))
            for i in range(n):
                rows.append(
                    {
                        "track": tr, "filter": f, "epoch": i, "t": t[i],
                        "vel_err_mean": ve[i], "vel_err_std": 0.4 * ve[i],
                        "att_err_mean": ae[i], "att_err_std": 0.3 * ae[i], "nees_mean": 6.0,
                        "north_err_mean": (k + 1) * 0.02 * t[i], "east_err_mean": -(k + 1) * 0.01 * t[i],
                        "north_true": north[i], "east_true": east[i],
                        "dvl_used": bool(not outage[i] and i > 0), "n_runs": 20,
                    }
                )
    return pd.DataFrame(rows)


def test_write_report(tmp_path: Path) -> None:
    filters = ("ukf", "anekf", "anukf")
    m = noisy_metrics(20, {"ukf": 0.12, "anekf": 0.1, "anukf": 0.09})
    m.to_parquet(tmp_path / "metrics.parquet")
    make_epochs(TRACKS, filters).to_parquet(tmp_path / "epochs.parquet")
    manifest = {"seed": 7, "data_dir": "/data/snapir", "wall_seconds": 12.5,
                "options": {"scenario": "nominal", "schedule": "constant"}}
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))

    path = write_report(tmp_path, reference="anukf", n_boot=300)
    assert path == tmp_path / "report.md"
    text = path.read_text()
    for f in filters:
        assert f"| {f}" in text
    assert "0.1172" in text and "0.0922" in text  # anukf.md Table I beside ours
    assert "ukf-nespm.md Table I" in text and "0.08" in text  # anukf in the NESPM paper too
    assert "anukf Imprv." in text and "95 % CI" in text and "eq 51" in text
    assert "/data/snapir" in text and "12.5 s" in text and "runs per track 20" in text
    assert text.index("## Verdict") < text.index("## Caveats") < text.index("## Track-averaged")
    assert "[docs/report.md](" in text and "## Definitions" not in text  # the definitions live in docs/report.md
    pngs = sorted((tmp_path / "figures").glob("*.png"))
    assert len(pngs) == 3 * len(TRACKS)  # vel, att, path: the epochs have neither HPE nor ANEES nor axes
    for p in pngs:
        assert p.stat().st_size > 5_000
        assert f"(figures/{p.name})" in text


def test_write_report_outage_without_epochs(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    vel = {(tr, f): b + 0.01 * rng.standard_normal(10) for tr in TRACKS for f, b in (("anekf", 0.2), ("anukf", 0.1))}
    make_metrics(vel, scenario="outage").to_parquet(tmp_path / "metrics.parquet")
    text = write_report(tmp_path, n_boot=100).read_text()
    assert "0.222" in text and "0.1183" in text  # anukf.md Table II
    assert "0.1172" not in text  # Table I is for the nominal scenario
    assert "epochs.parquet` is absent" in text
    assert not (tmp_path / "figures").exists()


def test_published_dash_for_unpublished_filter(tmp_path: Path) -> None:
    """anukf.md Table I has rows for two of the filters run (ukf, anukf): shown, anekf's row dashed."""
    m = noisy_metrics(12, {"ekf": 0.15, "ukf": 0.12, "anukf": 0.1})
    m.to_parquet(tmp_path / "metrics.parquet")
    text = write_report(tmp_path, n_boot=50).read_text()
    pub = text.split("## Comparison with the published tables")[1].split("## Figures")[0]
    assert "0.1172" in pub
    assert not any(line.startswith("| ekf ") for line in pub.splitlines())  # not in a published table
    anekf_row = next(line for line in pub.splitlines() if line.startswith("| anekf "))
    assert anekf_row.count("—") == 4  # not run: our VRMSE, our Imprv., our MRMSE, our Imprv.
    ukf_row = next(line for line in pub.splitlines() if line.startswith("| ukf "))
    assert "21.3 %" in ukf_row and "5.4 %" in ukf_row  # published Imprv. of ANUKF over UKF
    # ukf-nespm.md Table I has a row for anukf only: not shown, named in the note
    assert "**ukf-nespm.md Table I**" not in pub
    assert "ukf-nespm.md Table I [scenario `nominal`] needs anukf-nespm, anukf" in pub
    assert "anukf Imprv." in text  # default reference: the last filter


def test_published_table_omitted_when_rows_missing(tmp_path: Path) -> None:
    """The main job's filters (ekf, ukf, ukf-nespm): no published table has two of them, so no
    table of dashes, one line naming the tables and the filters they need."""
    m = noisy_metrics(12, {"ekf": 0.15, "ukf": 0.12, "ukf-nespm": 0.1})
    m.to_parquet(tmp_path / "metrics.parquet")
    text = write_report(tmp_path, n_boot=50).read_text()
    pub = text.split("## Comparison with the published tables")[1].split("## Figures")[0]
    assert "0.1172" not in pub and "| Method |" not in pub
    lines = [ln for ln in pub.splitlines() if ln.strip()]
    assert len(lines) == 1
    assert lines[0].startswith("No published table has rows for at least two of the filters run (ekf, ukf, ukf-nespm")
    for needed in ("anukf.md Table I [scenario `nominal`] needs ukf, anekf, anukf",
                   "ukf-nespm.md Table I [scenario `nominal`] needs anukf-nespm, anukf",
                   "needs anekf, anukf"):
        assert needed in lines[0]
    assert published_tables(["ekf", "ukf", "ukf-nespm"], "nominal", min_filters=2) == []
    assert len(published_tables(["ekf", "ukf", "ukf-nespm"], "nominal")) == 1  # default: one shared filter


def test_load_results_errors(tmp_path: Path) -> None:
    with pytest.raises(NespmError, match="results folder not found") as err:
        load_results(tmp_path / "nope")
    assert "\n" not in str(err.value)
    with pytest.raises(NespmError, match="metrics.parquet not found") as err:
        write_report(tmp_path)
    assert "\n" not in str(err.value)
    pd.DataFrame({"track": [1], "filter": ["ukf"]}).to_parquet(tmp_path / "metrics.parquet")
    with pytest.raises(NespmError, match="missing column"):
        load_results(tmp_path)


def test_load_results_optional_files(tmp_path: Path) -> None:
    noisy_metrics(3, {"ukf": 0.1}).to_parquet(tmp_path / "metrics.parquet")
    metrics, epochs, manifest = load_results(tmp_path)
    assert len(metrics) == 6 and epochs is None and manifest == {}


def test_published_tables_show_our_paired_improvement_of_the_proposed_method(tmp_path: Path) -> None:
    """anukf.md Table I beside ours: ANUKF's improvement over UKF and ANEKF, with intervals;
    ukf-nespm.md Table I: ANUKF-NESPM over ANUKF."""
    m = noisy_metrics(20, {"ukf": 0.12, "anekf": 0.11, "anukf": 0.10, "anukf-nespm": 0.09}, noise=0.002)
    m.to_parquet(tmp_path / "metrics.parquet")
    text = write_report(tmp_path, n_boot=200).read_text()
    pub = text.split("## Comparison with the published tables")[1].split("## Figures")[0]
    t1, t3 = pub.split("**anukf.md Table I**")[1], pub.split("**ukf-nespm.md Table I**")[1]
    ukf_row = next(line for line in t1.splitlines() if line.startswith("| ukf "))
    cells = [c.strip() for c in ukf_row.strip("|").split("|")]
    ours = float(cells[3].split(" %")[0])
    vr = {f: hand_vrmse(m, f) for f in ("ukf", "anukf")}
    assert ours == pytest.approx(100 * (vr["ukf"] - vr["anukf"]) / vr["ukf"], abs=0.051)
    assert "[" in cells[3] and cells[3].endswith("*")  # 0.12 vs 0.10 with 0.002 noise: excludes 0
    assert cells[4] == "21.3 %"
    anukf_row = next(line for line in t3.splitlines() if line.startswith("| anukf "))
    assert "8.8 %" in anukf_row  # published: (0.08 - 0.073) / 0.08
    assert "Imprv. of anukf-nespm" in pub


def test_improvement_point_lies_in_its_paired_interval_when_runs_diverge() -> None:
    """The baseline loses its worst runs (diverged): the improvement and its interval are both
    over the runs diverged in neither filter, so the point lies inside the interval."""
    rng = np.random.default_rng(3)
    vel = {}
    for tr in TRACKS:
        hard = np.r_[np.full(5, 2.0), np.full(25, 0.2)] + 0.01 * rng.standard_normal(30)  # 5 hard runs
        vel[(tr, "ekf")] = hard * 1.5
        vel[(tr, "ukf")] = hard
    m = make_metrics(vel)
    lost = (m["filter"] == "ekf") & (m["run"] < 5)  # ekf diverges on exactly the hard runs
    m.loc[lost, "diverged"] = True
    m.loc[lost, ["sse_vel", "sse_att", "vrmse", "mrmse"]] = np.nan
    t = filter_table(m, "ukf", n_boot=300).set_index("filter")
    r = t.loc["ekf"]
    assert r["vrmse_ci_lo"] <= r["vrmse_imprv"] <= r["vrmse_ci_hi"]
    assert r["vrmse_imprv"] == pytest.approx(100 / 3, abs=1.0)  # ukf errors are 1/1.5 of ekf's on shared runs
    # the per-filter track averages are over the runs no filter lost, so they agree with the paired
    # improvement (before issue 23 they compared ekf's easy runs with ukf's hard ones: -150 %,
    # ekf "better" because it lost the hard runs)
    assert 100 * (r["vrmse"] - t.loc["ukf", "vrmse"]) / r["vrmse"] == pytest.approx(100 / 3, abs=1.0)
    assert int(r["diverged"]) == 5 * len(TRACKS) and int(t.loc["ukf", "diverged"]) == 0


# ----------------------------------------------------------------------------- summary in words


def add_hpe(m: pd.DataFrame, factor: float = 10.0) -> pd.DataFrame:
    """The horizontal-position columns of metrics.parquet: per-run HPE = factor · vrmse."""
    m = m.copy()
    h = factor * m["vrmse"].to_numpy(float)
    m["sse_hpe"] = m["n_samples"] * h**2
    m["hpe_rms"] = h
    m["hpe_final"] = 1.5 * h
    m["hpe_max"] = 2.0 * h
    m["distance"] = 1000.0 + m["track"]
    m["hpe_final_pct"] = 100 * m["hpe_final"] / m["distance"]
    return m


def section(text: str, name: str) -> str:
    """The body of the report section ``## name`` (up to the next section)."""
    return text.split(f"## {name}\n")[1].split("\n## ")[0].strip()


def verdict_row(text: str, metric: str) -> list[str]:
    """The cells of the verdict table's row of ``metric`` (e.g. ``velocity RMSE``)."""
    line = next(ln for ln in section(text, "Verdict").splitlines() if ln.startswith(f"| {metric} "))
    return [c.strip() for c in line.strip().strip("|").split("|")]


def test_summary_clear_winner_beyond_threshold(tmp_path: Path) -> None:
    m = add_hpe(noisy_metrics(20, {"ukf": 0.12, "anekf": 0.11, "anukf": 0.09}, noise=0.002))
    comps = compare_filters(m, n_boot=400)
    assert set(comps["metric"]) == {"vrmse", "mrmse", "hpe_final", "hpe"}
    for key in ("vrmse", "mrmse", "hpe_final", "hpe"):
        c = comps[comps["metric"] == key].set_index("other")
        assert (c["best"] == "anukf").all() and set(c.index) == {"ukf", "anekf"}
        assert (c["verdict"] == "better").all() and c["significant"].all() and c["practical"].all()
        for other in ("ukf", "anekf"):  # the paired improvement of the best over the other
            assert c.loc[other, "imprv"] == pytest.approx(paired_improvement(m, other, "anukf", [key])[key], abs=1e-12)
            assert c.loc[other, "ci_lo"] < c.loc[other, "imprv"] < c.loc[other, "ci_hi"]
    m.to_parquet(tmp_path / "metrics.parquet")
    text = write_report(tmp_path, n_boot=400).read_text()
    assert text.index("## Verdict") < text.index("## Caveats") < text.index("## Track-averaged")
    vr = verdict_row(text, "velocity RMSE")
    # the reference (anukf, the last filter) is the best: compared with its closest competitor, anekf
    assert vr[1].startswith("`anukf` ") and vr[2].startswith("`anekf` ") and "reference" not in vr[2]
    r = comps[(comps["metric"] == "vrmse") & (comps["other"] == "anekf")].iloc[0]
    assert vr[3] == fmt_imprv(r["imprv"], r["ci_lo"], r["ci_hi"], "*")  # compare_filters' numbers
    assert vr[4:7] == ["yes", "yes", "40 (≥ 20 per track)"]
    assert vr[7] == "`anukf` is best (meaningfully better than every other filter)"
    pw = section(text, "Pairwise comparisons")
    row = next(ln for ln in pw.splitlines() if ln.startswith("| VRMSE |"))
    assert "vs `ukf`" in row and "vs `anekf`" in row and "meaningful" in row and "no practical difference" not in row
    assert verdict_row(text, "horizontal position error, RMS")[1].startswith("`anukf` ")
    assert verdict_row(text, "horizontal position error, final")[1].startswith("`anukf` ")
    assert section(text, "Caveats").startswith("None")  # no loss, enough runs: nothing to warn about


def test_summary_significant_but_below_practical_threshold(tmp_path: Path) -> None:
    """b = a · 0.998 in every run: 0.2 % better with a tight interval excluding 0 — significant,
    but under the 1 % threshold: "no practical difference"; with practical_pct 0.1 it is meaningful."""
    rng = np.random.default_rng(2)
    vel = {}
    for tr in TRACKS:
        a = 0.1 + 0.01 * rng.standard_normal(20)
        vel[(tr, "ekf")] = a
        vel[(tr, "ukf")] = a * 0.998 * (1 + 1e-4 * rng.standard_normal(20))
    m = make_metrics(vel)
    c = compare_filters(m, n_boot=400).set_index("metric")
    r = c.loc["vrmse"]
    assert r["best"] == "ukf" and r["other"] == "ekf"
    assert r["imprv"] == pytest.approx(0.2, abs=0.02)
    assert r["significant"] and not r["practical"] and r["verdict"] == "no practical difference"
    m.to_parquet(tmp_path / "metrics.parquet")
    text = write_report(tmp_path, n_boot=400).read_text()
    vr = verdict_row(text, "velocity RMSE")
    assert vr[7] == "no practical difference between the filters"
    assert vr[3].endswith("] *") and vr[4] == "yes" and vr[5] == "no"  # significant, below the threshold
    assert f"practical threshold {PRACTICAL_PCT:g} %" in section(text, "Verdict")
    # the keyword reaches the words: with 0.1 % the same 0.2 % is practically meaningful too
    text2 = write_report(tmp_path, n_boot=400, practical_pct=0.1).read_text()
    vr2 = verdict_row(text2, "velocity RMSE")
    assert "`ukf` is best" in vr2[7] and vr2[5] == "yes" and "practically (≥ 0.1 %)" in section(text2, "Verdict")
    assert compare_filters(m, n_boot=100, practical_pct=0.1).set_index("metric").loc["vrmse", "verdict"] == "better"
    with pytest.raises(NespmError, match="--practical"):
        write_report(tmp_path, n_boot=10, practical_pct=-1)


def test_summary_no_difference_when_interval_includes_zero() -> None:
    m = noisy_metrics(30, {"ukf": 0.1, "anukf": 0.1}, noise=0.03)
    r = compare_filters(m, n_boot=400).set_index("metric").loc["vrmse"]
    assert r["ci_lo"] < 0 < r["ci_hi"] and not r["significant"]
    assert r["verdict"] in ("no practical difference", "not significant")


def test_summary_small_sample_warning_and_no_star(tmp_path: Path) -> None:
    """4 runs per track, a large clear difference: the interval excludes 0 but is not starred
    or called significant; the Summary warns."""
    m = noisy_metrics(4, {"ekf": 0.15, "ukf": 0.10}, noise=0.002)
    c = compare_filters(m, n_boot=300).set_index("metric").loc["vrmse"]
    assert c["excludes_0"] and not c["significant"] and c["verdict"] == "too few runs" and c["pairs_min"] == 4
    t = filter_table(m, "ukf", n_boot=300).set_index("filter")
    assert t.loc["ekf", "vrmse_ci_excludes_0"] and not t.loc["ekf", "vrmse_significant"]
    assert t.loc["ekf", "pairs_min"] == 4
    m.to_parquet(tmp_path / "metrics.parquet")
    text = write_report(tmp_path, n_boot=300).read_text()
    cav = section(text, "Caveats")
    assert "(track 5: 4, track 6: 4)" in cav
    assert f"fewer than {MIN_PAIRED_RUNS} runs kept by both" in cav and "35 distinct resamples" in cav  # C(7, 4)
    assert text.count("distinct resamples") == 1  # said once, not per comparison
    vr = verdict_row(text, "velocity RMSE")
    assert vr[7] == "not assessed (too few paired runs)" and vr[4] == "not assessed †" and vr[3].endswith("†")
    main = text.split("## Track-averaged results")[1].split("## Per-track")[0]
    ekf_row = next(ln for ln in main.splitlines() if ln.startswith("| ekf "))
    assert "†" in ekf_row and "*" not in ekf_row
    # 10 runs per track: trusted, starred, no caveat
    m10 = noisy_metrics(10, {"ekf": 0.15, "ukf": 0.10}, noise=0.002)
    m10.to_parquet(tmp_path / "metrics.parquet")
    text10 = write_report(tmp_path, n_boot=300).read_text()
    assert "distinct resamples" not in text10
    ekf10 = next(ln for ln in text10.split("## Track-averaged results")[1].splitlines() if ln.startswith("| ekf "))
    assert "*" in ekf10 and "†" not in ekf10


def test_summary_best_uses_pairs_when_runs_diverge() -> None:
    """ekf diverges on the 5 hard runs: over its own runs its VRMSE is lower than ukf's, but on
    the runs both kept ukf is better — the Summary names ukf, with the paired point."""
    rng = np.random.default_rng(3)
    vel = {}
    for tr in TRACKS:
        hard = np.r_[np.full(5, 2.0), np.full(25, 0.2)] + 0.01 * rng.standard_normal(30)
        vel[(tr, "ekf")] = hard * 1.5
        vel[(tr, "ukf")] = hard
    m = make_metrics(vel)
    lost = (m["filter"] == "ekf") & (m["run"] < 5)
    m.loc[lost, "diverged"] = True
    m.loc[lost, ["sse_vel", "sse_att", "vrmse", "mrmse"]] = np.nan
    t = filter_table(m, "ukf", n_boot=0).set_index("filter")
    # over the runs no filter lost ekf is worse (over its own runs, before issue 23, it looked better)
    assert t.loc["ekf", "vrmse"] > t.loc["ukf", "vrmse"]
    r = compare_filters(m, n_boot=300).set_index("metric").loc["vrmse"]
    assert r["best"] == "ukf" and r["other"] == "ekf" and r["verdict"] == "better"
    assert r["imprv"] == pytest.approx(paired_improvement(m, "ekf", "ukf")["vrmse"], abs=1e-12)
    assert r["imprv"] == pytest.approx(100 / 3, abs=1.0) and r["pairs_min"] == 25


def test_definitions_match_the_code(tmp_path: Path) -> None:
    """The definitions moved to docs/report.md; the report links to it, relative to the folder."""
    from nespm_cli.reports.markdown import REPORT_DOCS

    noisy_metrics(12, {"ukf": 0.12, "anukf": 0.09}).to_parquet(tmp_path / "metrics.parquet")
    text = write_report(tmp_path, n_boot=50).read_text()
    link = text.split("[docs/report.md](")[1].split(")")[0]
    assert (tmp_path / link).resolve() == REPORT_DOCS.resolve()
    defs = REPORT_DOCS.read_text()
    flat = " ".join(defs.split())
    assert "Every improvement, its point and its interval, is computed over the runs that neither filter" in flat
    assert f"than {MIN_PAIRED_RUNS} paired runs on some track" in flat
    assert "an inconsistent run keeps its errors in every average" in flat
    for col in ("Best filter", "runner-up", "Improvement over the runner-up [95 % CI]", "statistically (excludes 0)",
                "practically (≥ p %)", "pairs", "verdict", "lost: best, runner-up", "Common survivors",
                "RTS smoother floor"):
        assert f"| {col}" in defs, col


# ----------------------------------------------------------------------------- formatting


def test_interval_formatting_distinguishes_close_values() -> None:
    assert fmt_imprv(-0.0076, -0.0091, -0.0061, "*") == "-0.0076 % [-0.0091, -0.0061] *"
    assert fmt_imprv(52.5, 42.3, 61.0) == "52.5 % [42.3, 61.0]"  # papers' one decimal for wide ones
    assert fmt_imprv(-0.113, -0.147, -0.094, "†") == "-0.113 % [-0.147, -0.094] †"  # was -0.1 % [-0.1, -0.1]
    assert fmt_ci(-0.147, -0.094, True) == "[-0.147, -0.094] % *"
    assert fmt_imprv(1.0, np.nan, np.nan) == "1.0 %" and fmt_imprv(np.nan, 0.0, 1.0) == "—"
    assert fmt_imprv(10.0, 10.0, 10.0) == "10.0 % [10.0, 10.0]"  # a collapsed interval stays short
    assert fmt_imprv(-0.0004, -0.3, 0.3) == "0.00 % [-0.30, 0.30]"  # no "-0.00"
    rng = np.random.default_rng(0)
    for _ in range(300):  # three distinct values always print as three distinct strings
        centre, width = rng.normal(0, 10) * 10.0 ** rng.integers(-3, 2), 10.0 ** rng.uniform(-5, 1)
        lo, hi = centre - width * rng.random(), centre + width * rng.random()
        point = lo + (hi - lo) * rng.uniform(0.05, 0.95)
        text = fmt_imprv(point, lo, hi)
        p, rest = text.split(" % [")
        a, b = rest.rstrip("]").split(", ")
        assert len({p, a, b}) == 3, text
        d = decimals(point, lo, hi)
        assert 10 ** -d <= (hi - lo), text  # the last digit is finer than the interval width


def test_nees_band_words(tmp_path: Path) -> None:
    m = noisy_metrics(20, {"ekf": 0.12, "ukf": 0.11, "ukf-nespm": 0.1})
    m.loc[m["filter"] == "ekf", "nees"] = 6.1  # inside the 40-run band
    m.loc[m["filter"] == "ukf", "nees"] = 12.0  # above
    m.loc[m["filter"] == "ukf-nespm", "nees"] = 2.0  # below
    lo, hi = nees_band(6, 40)
    c = nees_consistency(m).set_index("filter")
    assert c.loc["ekf", "consistency"] == "consistent"
    assert c.loc["ukf", "consistency"] == "overconfident"
    assert c.loc["ukf-nespm", "consistency"] == "conservative"
    assert (c["nees_n"] == 40).all() and c.loc["ekf", "nees_lo"] == pytest.approx(lo) and c.loc["ekf", "nees_hi"] == pytest.approx(hi)
    ins = noisy_metrics(20, {"ins": 0.5, "ekf": 0.1})
    ins.loc[ins["filter"] == "ins", "nees"] = np.nan
    assert nees_consistency(ins).set_index("filter").loc["ins", "consistency"] == "—"
    m.to_parquet(tmp_path / "metrics.parquet")
    text = write_report(tmp_path, n_boot=50).read_text()
    band = f"[{lo:.2f}, {hi:.2f}]"
    main = text.split("## Track-averaged results")[1].split("## Per-track")[0]
    ukf_row = next(ln for ln in main.splitlines() if ln.startswith("| ukf "))
    assert f"| 12.00 | {band} | overconfident |" in ukf_row
    an = verdict_row(text, "ANEES (6 dof)")  # the filter closest to 6, beside the reference
    assert an[1] == "`ekf` 6.10" and an[2] == "`ukf` 12.00: overconfident"  # the runner-up
    assert an[3] == "—" and an[6] == "40" and an[7] == f"closest to 6: consistent (band {band})"
    per_track = text.split("## Per-track results")[1].split("## Horizontal")[0]
    lo20, hi20 = nees_band(6, 20)
    assert f"[{lo20:.2f}, {hi20:.2f}]" in per_track


# ----------------------------------------------------------------------------- horizontal position


def test_horizontal_table_values() -> None:
    m = add_hpe(noisy_metrics(10, {"ekf": 0.12, "ukf": 0.1}))
    ht = horizontal_table(m)
    avg = ht[ht["track"].isna()].set_index("filter")
    per = ht[ht["track"].notna()].set_index(["track", "filter"])
    for f in ("ekf", "ukf"):
        rms = []
        for tr in TRACKS:
            d = m[(m["track"] == tr) & (m["filter"] == f)]
            assert per.loc[(tr, f), "hpe_final"] == pytest.approx(d["hpe_final"].mean(), abs=1e-12)
            assert per.loc[(tr, f), "hpe_final_pct"] == pytest.approx(d["hpe_final_pct"].mean(), abs=1e-12)
            assert per.loc[(tr, f), "distance"] == 1000.0 + tr
            rms.append(d["sse_hpe"].sum() / d["n_samples"].sum())
            assert per.loc[(tr, f), "hpe_rms"] == pytest.approx(np.sqrt(rms[-1]), abs=1e-12)
        assert avg.loc[f, "hpe_rms"] == pytest.approx(np.sqrt(np.mean(rms)), abs=1e-12)
        assert avg.loc[f, "hpe_final"] == pytest.approx(per.loc[[(t, f) for t in TRACKS], "hpe_final"].mean(), abs=1e-12)
    assert horizontal_table(noisy_metrics(3, {"ukf": 0.1})) is None  # an older folder


def make_hpe_epochs(tracks, filters, n: int = 300) -> pd.DataFrame:
    ep = make_epochs(tracks, filters, n)
    k = ep["filter"].map({f: i + 1 for i, f in enumerate(filters)})
    ep["hpe_mean"] = np.hypot(ep["north_err_mean"], ep["east_err_mean"]) + 0.5 * k
    ep["hpe_std"] = 0.2 * ep["hpe_mean"]
    return ep


def test_report_horizontal_section_and_figure(tmp_path: Path) -> None:
    """The report's horizontal-position section has its table columns and one HPE figure per track."""
    filters = ("ekf", "ukf")
    m = add_hpe(noisy_metrics(12, {"ekf": 0.12, "ukf": 0.1}))
    m.to_parquet(tmp_path / "metrics.parquet")
    make_hpe_epochs(TRACKS, filters).to_parquet(tmp_path / "epochs.parquet")
    text = write_report(tmp_path, n_boot=50).read_text()
    sec = text.split("## Horizontal position error")[1].split("## Comparison")[0]
    assert ("| Track | Method | distance [m] | final HPE [m] | RMS HPE [m] | final HPE [% of distance] | CEP50 [m] "
            "| R95 [m] | diverged |") in sec
    ht = horizontal_table(m)
    for r in ht.itertuples(index=False):
        label = "average" if r.track is None else str(r.track)
        assert f"| {label} | {r.filter} | {r.distance:.1f} | {r.hpe_final:.4g} | {r.hpe_rms:.4g} | {r.hpe_final_pct:.3g} |" in sec
    for tr in TRACKS:
        png = tmp_path / "figures" / f"hpe_track{tr}.png"
        assert png.stat().st_size > 5_000 and f"(figures/hpe_track{tr}.png)" in text
    for tr in TRACKS:  # the lead figure: horizontal error against the distance travelled
        assert f"(figures/hpe_distance_track{tr}.png)" in text
    assert len(list((tmp_path / "figures").glob("*.png"))) == 5 * len(TRACKS)
    # an older folder: no HPE metrics columns, no hpe_mean in epochs -> a note, no HPE figure, no error
    old = tmp_path / "old"
    old.mkdir()
    noisy_metrics(12, {"ekf": 0.12, "ukf": 0.1}).to_parquet(old / "metrics.parquet")
    make_epochs(TRACKS, filters).to_parquet(old / "epochs.parquet")
    text_old = write_report(old, n_boot=20).read_text()
    assert "No horizontal-position columns" in text_old
    assert "horizontal position error" not in section(text_old, "Verdict")
    assert not list((old / "figures").glob("hpe_*.png"))
    assert len(list((old / "figures").glob("*.png"))) == 3 * len(TRACKS)


def test_render_report_keyword_defaults() -> None:
    import inspect

    for fn in (write_report, render_report):
        assert inspect.signature(fn).parameters["practical_pct"].default == PRACTICAL_PCT == 1.0
