"""The t = 0 rule: the papers' sums keep every epoch, the posterior sums leave the first one out."""
import numpy as np
import pandas as pd

from nespm_cli.experiments.metrics import POSTERIOR_COLUMNS, EpochErrors, run_metrics
from nespm_cli.reports.stats import posterior_view, paired_improvement


def _errors(first: float, rest: float, R: int = 3, N: int = 5) -> EpochErrors:
    vel = np.full((R, N), rest)
    vel[:, 0] = first
    ne = np.zeros((R, N, 2))
    ne[..., 0] = vel
    return EpochErrors(vel=vel, att=vel / 10, nees=np.full((R, N), 6.0), ne=ne)


def test_posterior_sums_leave_out_the_first_epoch():
    m = run_metrics(_errors(2.0, 1.0), np.array([False, False, True]))
    assert m["sse_vel"][0] == 4.0 + 4 * 1.0  # papers: every epoch including t = 0
    assert m["sse_vel_post"][0] == 4 * 1.0
    assert np.isclose(m["sse_att_post"][0], 4 * 0.01) and m["sse_hpe_post"][0] == 4.0
    assert (m["n_post"] == 4).all() and (m["n_samples"] == 5).all()
    assert np.isnan(m["sse_vel_post"][2]) and np.isnan(m["sse_hpe_post"][2])  # lost: NaN like the others
    assert set(POSTERIOR_COLUMNS.values()) <= set(m)


def test_a_common_initial_error_no_longer_dilutes_an_improvement():
    # filter a halves the error after t = 0; both start with the same large initial error
    rows = []
    for name, rest in (("a", 0.5), ("b", 1.0)):
        m = run_metrics(_errors(3.0, rest, R=4), np.zeros(4, bool))
        rows.append(pd.DataFrame({"track": 1, "filter": name, "run": np.arange(4), **m}))
    metrics = pd.concat(rows, ignore_index=True)
    papers = paired_improvement(metrics, "b", "a")["vrmse"]
    post = paired_improvement(posterior_view(metrics), "b", "a")["vrmse"]
    assert np.isclose(post, 50.0)  # sqrt(4 · 0.25 / 4) against sqrt(4 · 1 / 4)
    assert np.isclose(papers, 100 * (1 - np.sqrt((9 + 1) / 5) / np.sqrt((9 + 4) / 5)))
    assert papers < post
    # a folder without the posterior columns is returned as it is (the caller says so once)
    old = metrics.drop(columns=list(POSTERIOR_COLUMNS.values()))
    same = posterior_view(old)
    assert same.equals(old) and same.attrs["posterior"] is False and "posterior" not in old.attrs
