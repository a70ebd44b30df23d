"""One wording of consistency (reports/wording.py, verdict.consistency_summary): the mean NEES only places the
average against its band and, outside it, names the block that drives it; the per-block words judge."""
from __future__ import annotations

import numpy as np
import pandas as pd

from nespm_cli.reports.wording import block_cause, mean_nees_place, mean_nees_words


def blocks(vel_mean: float, vel_above: float, vel_below: float, att_mean: float) -> pd.DataFrame:
    rows = [("vel", "velocity", vel_mean, vel_above, vel_below, "mixed"),
            ("att", "attitude", att_mean, 0.0, 0.6, "conservative"),
            ("ba", "accelerometer bias", 30.0, 0.9, 0.0, "overconfident")]
    return pd.DataFrame([{"track": None, "filter": "ekf", "kind": "ANEES", "item": i, "name": n, "dof": 3, "mean": m,
                          "inside": 1 - a - b, "above": a, "below": b, "epochs": 100, "word": w}
                         for i, n, m, a, b, w in rows])


def test_the_cause_is_the_nees_block_farthest_from_its_dof():
    t = blocks(4.2, 0.23, 0.71, 2.1)
    cause = block_cause(t, "above")
    # the bias block is not in the 6-DOF NEES: velocity drives it, and its mixed shares say how
    assert cause.startswith("velocity (mean ANEES 4.2 of 3; 23 % of its epochs above the bounds, 71 % below")
    assert "a few epochs far above pull the mean up" in cause
    assert block_cause(t, "below").startswith("attitude (mean ANEES 2.1 of 3")
    assert block_cause(t, "inside") == ""
    assert mean_nees_place(9.5, 3.84, 8.63) == "above" and mean_nees_place(5.0, 3.84, 8.63) == "inside"
    assert mean_nees_words(9.5, 3.84, 8.63, cause) == f"mean NEES 9.5 above its band [3.84, 8.63], driven by {cause}"
    assert mean_nees_words(float("nan"), 3.84, 8.63) == ""


def test_summary_agrees_with_the_blocks_and_gives_the_cause():
    from nespm_cli.reports.verdict import consistency_row, consistency_summary

    t = blocks(4.2, 0.23, 0.71, 2.1)
    runs = 8
    m = pd.DataFrame({"track": 5, "filter": "ekf", "run": np.arange(runs), "nees": 12.0, "nees_post": 9.5,
                      "diverged": False, **{c: 1.0 for c in ("sse_vel", "sse_att", "sse_hpe", "sse_vel_post", "sse_att_post",
                                                            "sse_hpe_post")}, "n_samples": 60, "n_post": 59})
    words = consistency_summary(t, m)["ekf"]
    # the block words first (the judgement), then where the mean lies and why: no second, contradicting word
    assert words.startswith("overconfident: accelerometer bias 10 %; mixed: velocity 6 %; conservative: attitude 40 %")
    assert "mean NEES 9.5 above its band" in words and "driven by velocity" in words  # nees_post: after t = 0
    assert "overconfident" not in words.split("; mean NEES")[1]
    row = consistency_row(t, ["ekf"], m)
    assert row["verdict"] == words
    inside = m.assign(nees_post=6.0)
    assert consistency_summary(t, inside)["ekf"] == "overconfident: accelerometer bias 10 %; mixed: velocity 6 %; " \
                                                    "conservative: attitude 40 %"
    assert consistency_summary(None, m)["ekf"] == "overconfident"  # no block table: the mean's band is the judgement
