"""The verdict-first report: the verdict table (its numbers are compare_filters'), the common
survivors, RTS-smoother floors never best nor reference, the final-HPE comparison, each caveat once."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import assert_one_error_line, nespm
from nespm_cli.errors import NespmError
from nespm_cli.reports import stats
from nespm_cli.reports.caveats import caveats
from nespm_cli.reports.comparisons import compare_filters
from nespm_cli.reports.dispatch import write_report
from nespm_cli.reports.markdown import fmt_imprv
from nespm_cli.reports.sweep_data import default_baseline
from nespm_cli.reports.tables import default_reference, filter_table
from nespm_cli.reports.verdict import verdict_table

TRACKS = (5, 6)


def metrics_of(levels: dict[str, float], runs: int = 20, noise: float = 0.002, seed: int = 4,
               nees: dict[str, float] | None = None) -> pd.DataFrame:
    """metrics.parquet rows (with the HPE columns) for filters whose per-run VRMSE is level + noise;
    MRMSE = 0.1 VRMSE, HPE = 10 VRMSE, final HPE = 15 VRMSE split 0.6 / 0.8 north / east."""
    rng = np.random.default_rng(seed)
    rows = []
    for tr in TRACKS:
        base = rng.standard_normal(runs)  # the same realization for every filter: paired
        for f, lev in levels.items():
            v = lev * (1 + 0.02 * base) + noise * rng.standard_normal(runs)
            for r in range(runs):
                n = 300 + r
                h = 10 * v[r]
                rows.append({"track": tr, "filter": f, "run": r, "scenario": "nominal", "schedule": "constant",
                             "vrmse": v[r], "mrmse": 0.1 * v[r], "sse_vel": n * v[r] ** 2,
                             "sse_att": n * (0.1 * v[r]) ** 2, "n_samples": n,
                             "nees": (nees or {}).get(f, 6.0 + v[r]), "diverged": False, "inconsistent": False,
                             "diverged_reason": "", "sse_hpe": n * h**2, "hpe_rms": h, "hpe_final": 1.5 * h,
                             "north_final": 0.9 * h, "east_final": 1.2 * h, "hpe_max": 2 * h,
                             "distance": 1000.0 + tr, "hpe_final_pct": 0.15 * h})
    m = pd.DataFrame(rows)  # posterior sums (the verdict's) equal to the papers' here
    return m.assign(sse_vel_post=m["sse_vel"], sse_att_post=m["sse_att"], sse_hpe_post=m["sse_hpe"],
                    n_post=m["n_samples"])


def lose(m: pd.DataFrame, filt: str, runs, reason: str = "attitude") -> pd.DataFrame:
    m = m.copy()
    bad = (m["filter"] == filt) & m["run"].isin(list(runs))
    m.loc[bad, "diverged"] = True
    m.loc[bad, "diverged_reason"] = reason
    m.loc[bad, ["sse_vel", "sse_att", "vrmse", "mrmse", "sse_hpe", "hpe_final", "hpe_rms", "north_final",
                "east_final", "hpe_final_pct"]] = np.nan
    return m


def cells(text: str, metric: str) -> list[str]:
    body = text.split("## Verdict\n")[1].split("\n## ")[0]
    line = next(ln for ln in body.splitlines() if ln.startswith(f"| {metric} "))
    return [c.strip() for c in line.strip().strip("|").split("|")]


def test_verdict_rows_are_compare_filters_rows() -> None:
    """Best filter and interval: the compare_filters row of (metric, best, reference); over the runner-up
    when the best is the reference."""
    m = metrics_of({"ekf": 0.12, "ukf": 0.10, "ukf-nespm": 0.11})
    comps = compare_filters(m, n_boot=300)
    vt = verdict_table(m, n_boot=300).set_index("metric")
    assert vt.attrs["reference"] == "ukf-nespm" and not vt.attrs["any_lost"]
    assert list(vt.index) == ["vrmse", "mrmse", "hpe_final", "hpe", "anees"]
    for key in ("vrmse", "mrmse", "hpe_final", "hpe"):
        c = comps[(comps["metric"] == key) & (comps["other"] == "ukf-nespm")].iloc[0]
        r = vt.loc[key]
        assert r["best"] == c["best"] == "ukf" and r["other"] == "ukf-nespm" and r["other_is_reference"]
        for col in ("imprv", "ci_lo", "ci_hi", "pairs_min", "significant", "practical", "verdict"):
            assert r[col] == c[col], (key, col)
        assert r["imprv"] == pytest.approx(stats.paired_improvement(m, "ukf-nespm", "ukf", [key])[key], abs=1e-12)
        assert r["pairs"] == 2 * 20
        for col in ("imprv", "ci_lo", "ci_hi", "pairs"):  # no run lost: the survivors are all runs
            assert r[f"s_{col}"] == r[col]
    # the reference is the best: compared with its closest competitor
    vt2 = verdict_table(m, "ukf", n_boot=300).set_index("metric")
    c = comps[comps["metric"] == "vrmse"]
    runner = c.loc[c["imprv"].idxmin(), "other"]
    assert runner == "ukf-nespm" and vt2.loc["vrmse", "other"] == runner and not vt2.loc["vrmse", "other_is_reference"]
    assert vt2.loc["vrmse", "ci_lo"] == c.set_index("other").loc[runner, "ci_lo"]


def test_verdict_markdown_shows_those_numbers(tmp_path: Path) -> None:
    m = metrics_of({"ekf": 0.12, "ukf": 0.10, "ukf-nespm": 0.11})
    m.to_parquet(tmp_path / "metrics.parquet")
    text = write_report(tmp_path, n_boot=300).read_text()
    vt = verdict_table(m, n_boot=300).set_index("metric")
    r = vt.loc["vrmse"]
    row = cells(text, "velocity RMSE")
    assert row[1] == f"`ukf` {r['best_value']:.4g}" and row[2] == f"`ukf-nespm` {r['other_value']:.4g} (reference)"
    assert row[3] == fmt_imprv(r["imprv"], r["ci_lo"], r["ci_hi"], "*" if r["significant"] else "")
    assert row[4] == ("yes" if r["significant"] else "no") and row[5] == ("yes" if r["practical"] else "no")
    assert "Common survivors" not in text  # no loss: the same numbers are not repeated
    assert "No run was lost, so all runs are the common survivors." in text
    final = cells(text, "horizontal position error, final")
    f = vt.loc["hpe_final"]
    assert final[3] == fmt_imprv(f["imprv"], f["ci_lo"], f["ci_hi"], "*" if f["significant"] else "")


def test_final_hpe_is_compared_as_a_mean_over_runs_then_tracks() -> None:
    m = metrics_of({"ekf": 0.12, "ukf": 0.10})
    per = {f: np.mean([m[(m["track"] == t) & (m["filter"] == f)]["hpe_final"].mean() for t in TRACKS])
           for f in ("ekf", "ukf")}
    got = stats.paired_improvement(m, "ekf", "ukf", ["hpe_final"])["hpe_final"]
    assert got == pytest.approx(100 * (per["ekf"] - per["ukf"]) / per["ekf"], abs=1e-12)
    t = filter_table(m, "ukf", n_boot=0).set_index("filter")  # the table's own final HPE, the same mean
    assert t.loc["ekf", "hpe_final"] == pytest.approx(per["ekf"], abs=1e-12)
    reps = stats.paired_bootstrap(m, "ekf", "ukf", n_boot=200, keys=["hpe_final"])["hpe_final"]
    lo, hi = stats.percentile_ci(reps)
    assert lo < got < hi


def test_common_survivor_columns_with_lost_runs(tmp_path: Path) -> None:
    """ekf loses runs 0-4, ukf-nespm runs 5-7: the pair (ukf, ukf-nespm) keeps 17 runs per track, the
    common survivors are 12; the survivor columns are the same comparison on those 12."""
    m = lose(lose(metrics_of({"ekf": 0.12, "ukf": 0.10, "ukf-nespm": 0.11}), "ekf", range(5)), "ukf-nespm", (5, 6, 7))
    vt = verdict_table(m, n_boot=300).set_index("metric")
    assert vt.attrs["any_lost"]
    r = vt.loc["vrmse"]
    assert r["best"] == "ukf" and r["other"] == "ukf-nespm" and r["pairs"] == 2 * 17 and r["s_pairs"] == 2 * 12
    surv = m[~stats.lost_by_any(m)]
    assert r["s_imprv"] == pytest.approx(stats.paired_improvement(surv, "ukf-nespm", "ukf")["vrmse"], abs=1e-12)
    lo, hi = stats.percentile_ci(stats.paired_bootstrap(surv, "ukf-nespm", "ukf", n_boot=300)["vrmse"])
    assert (r["s_ci_lo"], r["s_ci_hi"]) == (lo, hi)
    m.to_parquet(tmp_path / "metrics.parquet")
    text = write_report(tmp_path, n_boot=300).read_text()
    row = cells(text, "velocity RMSE")
    assert len(row) == 13 and row[10] in ("yes", "no") and row[12] == "24 (≥ 12 per track)"
    assert "Common survivors: improvement [95 % CI]" in text
    assert "Lost (diverged) runs per filter: ekf 10, ukf 0, ukf-nespm 6 (" in text


def with_floor(m: pd.DataFrame, filt: str = "ekf", factor: float = 0.5) -> pd.DataFrame:
    """Add the RTS-smoother floor of ``filt``: its errors times ``factor`` (far below every filter)."""
    f = m[m["filter"] == filt].copy()
    f["filter"] = f"{filt}-rts"
    for c in ("vrmse", "mrmse", "hpe_rms", "hpe_final", "north_final", "east_final"):
        f[c] = factor * f[c]
    for c in ("sse_vel", "sse_att", "sse_hpe", "sse_vel_post", "sse_att_post", "sse_hpe_post"):
        f[c] = factor**2 * f[c]
    f["nees"] = 6.0  # the most consistent too: still never the best
    return pd.concat([m, f], ignore_index=True)


def test_smoother_floor_is_never_best_nor_reference(tmp_path: Path) -> None:
    m = with_floor(metrics_of({"ekf": 0.12, "ukf": 0.10}, nees={"ekf": 9.0, "ukf": 11.0}))
    assert default_reference(m) == "ukf"  # the last filter that is not a floor
    assert default_baseline(m[m["filter"] != "ekf"]) == "ukf"
    with pytest.raises(NespmError, match="RTS-smoother floor"):
        default_reference(m, "ekf-rts")
    with pytest.raises(NespmError, match="RTS-smoother floor"):
        default_baseline(m.assign(param="alpha", value=1.0), "ekf-rts")
    comps = compare_filters(m, n_boot=200)
    assert "ekf-rts" not in set(comps["best"]) | set(comps["other"])
    vt = verdict_table(m, n_boot=200).set_index("metric")
    assert "ekf-rts" not in set(vt["best"]) and "ekf-rts" not in set(vt["other"].dropna())
    own = filter_table(m, None, n_boot=0).set_index("filter")
    assert vt.loc["vrmse", "floor"] == "ekf-rts" and vt.loc["vrmse", "floor_value"] == own.loc["ekf-rts", "vrmse"]
    assert vt.loc["anees", "best"] == "ekf"  # 9 is nearer 6 than 11 (the floor's 6.0 does not count)
    m.to_parquet(tmp_path / "metrics.parquet")
    text = write_report(tmp_path, n_boot=200).read_text()
    assert cells(text, "velocity RMSE")[-1] == f"`ekf-rts` {own.loc['ekf-rts', 'vrmse']:.4g}"
    main = text.split("## Track-averaged results")[1].split("\n## ")[0]
    assert "| ekf-rts (RTS smoother floor) |" in main
    assert text.count("RTS-smoother floor (hindsight") == 1
    rc, out, err = nespm("report", tmp_path, "--baseline", "ekf-rts", "--n-boot", "10")
    assert_one_error_line(rc, out, err, "RTS-smoother floor")


def test_each_caveat_once(tmp_path: Path) -> None:
    """Few runs, lost runs, inconsistent runs and a floor: every caveat exactly once, not per comparison."""
    m = with_floor(lose(metrics_of({"ekf": 0.15, "ukf": 0.10, "ukf-nespm": 0.11}, runs=6), "ekf", (0,)))
    m.loc[(m["filter"] == "ukf") & (m["run"] == 3), "inconsistent"] = True
    m.to_parquet(tmp_path / "metrics.parquet")
    (tmp_path / "manifest.json").write_text(json.dumps({"options": {"scenario": "nominal"}}))
    text = write_report(tmp_path, n_boot=200).read_text()
    comps = compare_filters(m, n_boot=200)
    items = caveats(m, comps, stats.MIN_PAIRED_RUNS)
    assert len(items) == 4
    for phrase in ("distinct resample", "Lost (diverged) runs per filter", "Inconsistent runs (NEES test)",
                   "RTS-smoother floor (hindsight"):
        assert text.count(phrase) == 1, phrase
    assert "percentile bootstrap is unreliable" not in text  # the old per-pair sentence
    assert text.count("fewer than 10") == 1
    body = text.split("## Caveats\n")[1].split("\n## ")[0]
    assert all(f"- {c}" in body for c in items)
    assert "(track 5: 5, track 6: 5)" in body  # ekf lost run 0: 5 pairs per track


def test_every_caveat_absent_on_clean_results() -> None:
    m = metrics_of({"ekf": 0.12, "ukf": 0.10})
    assert caveats(m, compare_filters(m, n_boot=50), stats.MIN_PAIRED_RUNS) == []
