"""The report's rules (issue 30 item 5): the consistency judged per block from the share of epochs inside the
per-epoch bounds, the runner-up as the one 'compared with', loss counts, an undefined comparison that does not
turn the verdict into 'no clear winner', the same 'not assessed' rule in compare, the Run line, the floor row."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from nespm_cli.experiments.metrics import nees_band
from nespm_cli.reports.block_consistency import CONSISTENT_SHARE, block_consistency, consistency_words, epoch_shares
from nespm_cli.reports.cases_report import improvements_md
from nespm_cli.reports.comparisons import compare_filters
from nespm_cli.reports.markdown import header_line
from nespm_cli.reports.mc_markdown import _main_table
from nespm_cli.reports.tables import filter_table
from nespm_cli.reports.verdict import verdict_table
from nespm_cli.reports.verdict_markdown import verdict_intro, verdict_md
from nespm_cli.reports.wording import verdict_headline


def metrics_of(levels: dict[str, float], runs: int = 12, tracks=(5, 6), seed: int = 1) -> pd.DataFrame:
    """Paired runs: per-run VRMSE level · (1 + 2 % common) + 0.1 % own noise; posterior sums = 0.9 of the papers'."""
    rng = np.random.default_rng(seed)
    rows = []
    for tr in tracks:
        base = rng.standard_normal(runs)
        for f, lev in levels.items():
            v = lev * (1 + 0.02 * base) + 1e-3 * lev * rng.standard_normal(runs)
            for r in range(runs):
                n, h = 300, 10 * v[r]
                rows.append({"track": tr, "filter": f, "run": r, "scenario": "nominal", "schedule": "constant",
                             "vrmse": v[r], "mrmse": 0.1 * v[r], "sse_vel": n * v[r] ** 2, "sse_att": n * (0.1 * v[r]) ** 2,
                             "n_samples": n, "nees": 6.0, "diverged": False, "inconsistent": False, "diverged_reason": "",
                             "sse_hpe": n * h ** 2, "hpe_rms": h, "hpe_final": h, "north_final": h, "east_final": 0.0,
                             "hpe_max": h, "distance": 1000.0, "hpe_final_pct": 0.1 * h,
                             "sse_vel_post": 0.9 * n * v[r] ** 2, "sse_att_post": 0.9 * n * (0.1 * v[r]) ** 2,
                             "sse_hpe_post": 0.9 * n * h ** 2, "n_post": n - 1})
    return pd.DataFrame(rows)


def test_epoch_shares_against_the_chi_square_bounds():
    n = np.full(10, 8)
    lo, hi = nees_band(3, 8)
    x = np.array([3.0] * 7 + [hi * 1.01, hi * 2, lo * 0.5])
    inside, above, below, k = epoch_shares(x, n, 3)
    assert (inside, above, below, k) == (pytest.approx(0.7), pytest.approx(0.2), pytest.approx(0.1), 10)
    assert np.isnan(epoch_shares(np.full(3, np.nan), np.full(3, 8), 3)[0])


def _epochs(values: dict[str, dict[str, np.ndarray]]) -> pd.DataFrame:
    parts = []
    for f, cols in values.items():
        N = len(next(iter(cols.values())))
        parts.append(pd.DataFrame({"track": 5, "filter": f, "epoch": np.arange(N), "t": np.arange(N, dtype=float),
                                   "n_runs": 8, **cols}))
    return pd.concat(parts, ignore_index=True)


def test_consistency_is_judged_per_block_not_from_a_mean():
    N = 101
    lo, hi = nees_band(3, 8)
    calm = np.full(N, 3.0)
    # velocity inside at 90 % of the epochs after t = 0; attitude overconfident (4x) at 30 %: the time mean of
    # the two together (about 3.5 x 3) would pass a lenient band, the per-block rule does not
    vel = calm.copy()
    vel[1:11] = 10 * hi
    att = np.full(N, 4 * hi)
    att[1:31] = 3.0
    ep = _epochs({"ekf": {"nees_vel_mean": vel, "nees_att_mean": att}, "ukf": {"nees_vel_mean": calm,
                                                                                "nees_att_mean": calm}})
    t = block_consistency(ep).set_index(["filter", "item"])
    assert t.loc[("ekf", "vel"), "inside"] == pytest.approx(0.9) and t.loc[("ekf", "vel"), "word"] == "consistent"
    assert t.loc[("ekf", "att"), "inside"] == pytest.approx(0.3) and t.loc[("ekf", "att"), "word"] == "overconfident"
    assert t.loc[("ekf", "att"), "epochs"] == N - 1  # t = 0 is not judged
    words = consistency_words(block_consistency(ep))
    assert words == {"ekf": "overconfident: attitude 30 %", "ukf": "consistent"}
    assert consistency_words(block_consistency(ep), shares=False)["ekf"] == "overconfident: attitude"
    # conservative: below the bounds
    ep2 = _epochs({"ekf": {"nees_vel_mean": np.full(N, lo / 2)}})
    assert block_consistency(ep2)["word"].tolist() == ["conservative"]
    # mixed: 30 % of the epochs above the bounds and 70 % below (a mean would call it either)
    mix = np.full(N, lo / 2)
    mix[1:31] = 4 * hi
    t3 = block_consistency(_epochs({"ekf": {"nees_vel_mean": mix}}))
    assert t3["word"].tolist() == ["mixed"] and t3["above"].tolist() == [pytest.approx(0.3)]
    assert consistency_words(t3) == {"ekf": "mixed: velocity 0 %"}
    assert 0.5 < CONSISTENT_SHARE < 0.95


def test_the_verdict_consistency_row_and_the_runner_up():
    m = metrics_of({"ekf": 0.15, "ukf": 0.10, "ukf-nespm": 0.11})
    N = 51
    ep = _epochs({"ekf": {"nees_vel_mean": np.full(N, 30.0)}, "ukf": {"nees_vel_mean": np.full(N, 3.0)},
                  "ukf-nespm": {"nees_vel_mean": np.full(N, 3.0)}})
    vt = verdict_table(m, "ekf", n_boot=200, consistency=block_consistency(ep)).set_index("metric")
    # the best (ukf) is compared with its closest competitor (ukf-nespm), not the reference (ekf)
    assert vt.loc["vrmse", "best"] == "ukf" and vt.loc["vrmse", "other"] == "ukf-nespm"
    assert not vt.loc["vrmse", "other_is_reference"]
    assert vt.loc["vrmse", "imprv"] == pytest.approx(100 * (1 - 0.10 / 0.11), abs=0.3)
    assert vt.attrs["posterior"]
    # the posterior sums are 0.9 of the papers' over 299 of 300 epochs: the verdict's value is the posterior one
    assert vt.loc["vrmse", "best_value"] == pytest.approx(np.sqrt(0.9 * 300 / 299) * 0.10, rel=0.02)
    assert (vt.loc["vrmse", "best_lost"], vt.loc["vrmse", "other_lost"], vt.loc["vrmse", "runs"]) == (0, 0, 24)
    c = vt.loc["consistency"]
    assert c["best"] == "ukf" and c["best_value"] == 1.0 and c["verdict"] == "consistent"
    assert c["other"] == "ukf-nespm" and "ekf" not in (c["best"], c["other"])
    md = verdict_md(vt.reset_index(), compare_filters(m, n_boot=200), tracks=2)
    assert "| runner-up |" in md and "lost: best, runner-up" in md and "0 / 24, 0 / 24" in md
    row = next(line for line in md.splitlines() if line.startswith("| consistency"))
    assert "`ukf` velocity 100 %" in row


def test_an_undefined_comparison_does_not_hide_the_winner():
    comps = pd.DataFrame({"best": ["ukf"] * 2, "other": ["ekf", "iekf"], "verdict": ["better", "undefined"]})
    words = verdict_headline(comps)
    assert words.startswith("`ukf` is best") and "against `iekf` undefined" in words
    assert "no clear winner" not in words


def test_compare_says_not_assessed_like_report():
    imp = pd.DataFrame([{"case": "b", "filter": "ekf", "pairs": 8, "pairs_min": 8, "hpe": 26.5, "hpe_lo": 20.8,
                         "hpe_hi": 30.4, "hpe_significant": False, "hpe_mark": "†"},
                        {"case": "c", "filter": "ekf", "pairs": 20, "pairs_min": 10, "hpe": 26.5, "hpe_lo": 20.8,
                         "hpe_hi": 30.4, "hpe_significant": True, "hpe_mark": "*"}])
    rows = improvements_md(imp).splitlines()[2:]
    assert "26.5 % [20.8, 30.4] †" in rows[0] and "not assessed †" in rows[0]
    assert "26.5 % [20.8, 30.4] *" in rows[1] and "RMS horizontal error yes" in rows[1]


def test_run_line_names_layout_sensors_and_imu():
    m = metrics_of({"ekf": 0.1})
    man = {"options": {"imu": "synthetic", "sensors": ["dvl", "depth"]}, "filter_config": {"all": {"state": "15"}},
           "sensors": {"all": {"dvl": {"source": "recorded"}, "depth": {"source": "synthetic"}}}}
    line = header_line(m, man)
    assert "error state 15" in line and "sensors dvl (recorded), depth (synthetic)" in line and "imu synthetic" in line
    assert "error state —" in header_line(m, {})  # an old manifest


def test_the_floor_has_its_own_row_without_an_improvement():
    m = metrics_of({"ekf": 0.15, "ukf": 0.10})
    f = m[m["filter"] == "ekf"].assign(filter="ekf-rts")
    m = pd.concat([m[m["filter"] == "ekf"], f, m[m["filter"] == "ukf"]], ignore_index=True)
    text = _main_table(filter_table(m, "ukf", n_boot=50))
    rows = text.splitlines()[2:]
    assert rows[-1].startswith("| ekf-rts (RTS smoother floor) |")  # after the causal filters
    cells = [c.strip() for c in rows[-1].split("|")[1:-1]]
    assert cells[2] == cells[3] == cells[5] == cells[6] == "—"


def test_the_intro_says_which_epochs_once():
    assert "after t = 0" in verdict_intro("ukf", 100, 0, 1.0, False, posterior=True)
    old = verdict_intro("ukf", 100, 0, 1.0, False, posterior=False)
    assert "include the t = 0 error" in old and "diluted" in old
    m = metrics_of({"ekf": 0.15, "ukf": 0.10}).drop(columns=["sse_vel_post", "sse_att_post", "sse_hpe_post", "n_post"])
    assert not verdict_table(m, n_boot=50).attrs["posterior"]


def test_the_share_is_an_option():
    from nespm_cli.errors import NespmError

    N = 101
    lo, hi = nees_band(3, 8)
    att = np.full(N, 4 * hi)
    att[1:61] = 3.0  # 60 % inside
    ep = _epochs({"ekf": {"nees_att_mean": att}})
    assert block_consistency(ep)["word"].tolist() == ["overconfident"]
    t = block_consistency(ep, share=0.5)
    assert t["word"].tolist() == ["consistent"] and t.attrs["share"] == 0.5
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(NespmError, match="--consistent-share"):
            block_consistency(ep, share=bad)


def test_every_run_counted_uses_the_verdicts_epochs():
    from nespm_cli.reports.all_runs import run_errors

    m = metrics_of({"ekf": 0.15, "ukf": 0.10})
    e = run_errors(m, "vrmse")
    ukf = m[m["filter"] == "ukf"].set_index(["track", "run"])["vrmse"]
    assert np.allclose(e["ukf"].to_numpy(), np.sqrt(0.9 * 300 / 299) * ukf.loc[e.index].to_numpy(), rtol=1e-12)
    old = m.drop(columns=["sse_vel_post", "sse_att_post", "sse_hpe_post", "n_post"])
    assert np.allclose(run_errors(old, "vrmse")["ukf"].to_numpy(), ukf.loc[e.index].to_numpy(), rtol=0)


def test_an_old_folder_still_reports_and_says_so_once(tmp_path):
    import json

    from nespm_cli.reports.dispatch import write_report

    m = metrics_of({"ekf": 0.15, "ukf": 0.10}).drop(columns=["sse_vel_post", "sse_att_post", "sse_hpe_post", "n_post"])
    m.to_parquet(tmp_path / "metrics.parquet")
    (tmp_path / "manifest.json").write_text(json.dumps({"options": {"scenario": "nominal"}}))
    text = write_report(tmp_path, n_boot=50).read_text()
    assert text.count("include the t = 0 error") == 1 and "Errors are posterior" not in text
    vt = verdict_table(m, n_boot=50).set_index("metric")
    assert f"`ukf` {vt.loc['vrmse', 'best_value']:.4g}" in text  # the every-epoch value, as the tables
    assert vt.loc["vrmse", "best_value"] == pytest.approx(filter_table(m, None, n_boot=0).set_index("filter").loc["ukf", "vrmse"])


def test_without_epochs_the_nis_numbers_still_show():
    from nespm_cli.reports.mc_markdown import nis_md

    m = metrics_of({"ekf": 0.15}).assign(nis_dvl=2.5)
    text = nis_md(m, {"sensors": {"all": {"dvl": {"source": "synthetic"}}}})
    assert "| ekf | dvl | 2.5 | 3 |" in text
    assert nis_md(metrics_of({"ekf": 0.15}), {}) == ""
