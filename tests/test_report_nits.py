"""Small report fixes: the accepted-residual caveat in the sweep report, an exact-zero improvement without
ten zeros, the oracle share below 1 % and its common note said once, a consistency share printed on the side
of its threshold that its word is on, the docs link of a report outside the sources, and a tuned factor the
level pushes past the noise-scale limits (clipped, said, and ``mc --config tuned.toml`` reads it)."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import nespm
from nespm_cli.reports.block_consistency import consistency_md, consistency_words, share_text
from nespm_cli.reports.markdown import REPORT_DOCS, docs_line, fmt_ci, fmt_imprv, imprv_cells
from nespm_cli.reports.oracle_share import oracle_share, pct, share_md

pytestmark = pytest.mark.usefixtures("no_env_data_dir")


# ----------------------------------------------------------------------------- item 1: the sweep's caveats


def test_sweep_report_says_the_accepted_residual(tmp_path):
    """A sweep on a track run with ``--accept-residual``: its manifest's sentence is a caveat line of the sweep
    report, as in the Monte Carlo report (tests/test_accept_residual.py)."""
    from nespm_cli.data.tracks import write_akit
    from nespm_cli.reports.caveats import residual_caveats
    from test_accept_residual import MC, N, enu_track, manifest

    akit = tmp_path / "d"
    write_akit(enu_track(), akit)
    out = tmp_path / "sweep"
    rc, _, err = nespm("sweep", "--data-dir", akit, *MC, "--param", "acc-noise", "--values", "0.01,0.02",
                       "--accept-residual", "--out", out)
    assert rc == 0, err
    (line,) = residual_caveats(manifest(out))
    assert line.startswith(f"track {N}: convention residual accepted: ") and "ENU convention" in line
    rc, _, err = nespm("report", out, "--n-boot", "50", "--no-progress")
    assert rc == 0, err
    caveats = (out / "report.md").read_text(encoding="utf-8").split("## Caveats", 1)[1].split("\n## ", 1)[0]
    assert f"- {line}" in caveats.splitlines()


# ----------------------------------------------------------------------------- item 2: an exact zero


def test_an_exact_zero_improvement_prints_like_the_others():
    """A zero point beside a round-off interval (±1e-15 %) printed ten zeros (``0.0000000000 % [0.0000000000,
    0.0000000000]``): the interval's width does not show at ten decimals, so it takes the papers' one decimal, as
    ``fmt_pct(0.0)`` and a collapsed interval do."""
    assert fmt_imprv(0.0, -1e-15, 1e-15) == "0.0 % [0.0, 0.0]"
    assert fmt_imprv(0.0, 0.0, 1e-13, "*") == "0.0 % [0.0, 0.0] *"
    assert imprv_cells(0.0, -1e-15, 1e-15) == ("0.0 %", "[0.0, 0.0]")
    assert fmt_ci(-1e-15, 1e-15, False) == "[0.0, 0.0] %"
    assert fmt_imprv(0.0, 0.0, 0.0) == fmt_imprv(0.0, -1e-15, 1e-15)  # the same as an exact [0, 0]
    # a value closer to another than ten decimals show no longer drags every value to ten decimals
    assert fmt_imprv(0.5, 0.5 - 1e-13, 1.0) == "0.50 % [0.50, 1.00]"
    # a tiny non-zero value still shows its first digit, and real intervals are as before
    assert fmt_imprv(1.234e-7, 1.234e-7 - 5e-13, 1.234e-7 + 5e-13) == "0.0000001 % [0.0000001, 0.0000001]"
    assert fmt_imprv(-0.0076, -0.0091, -0.0061, "*") == "-0.0076 % [-0.0091, -0.0061] *"
    assert fmt_imprv(0.0, -0.3, 0.2) == "0.00 % [-0.30, 0.20]"


# ----------------------------------------------------------------------------- item 3: the oracle share


def test_a_small_share_prints_one_decimal():
    assert [pct(x) for x in (0.004, -0.0004, 0.0094, 0.0096, -0.0096, 0.52, -1.27, 0.0)] == [
        "0.4", "0.0", "0.9", "1", "-1", "52", "-127", "0.0"]


def frame(values: dict, runs: int = 12) -> pd.DataFrame:
    """A metrics frame of track 5: per filter a run's posterior squared-error sum ``values[f](run)`` over 10 epochs."""
    return pd.DataFrame([{"track": 5, "filter": f, "run": r, "diverged": False, "sse_vel": 10 * v(r) ** 2,
                          "sse_att": 1.0, "n_samples": 10} for f, v in values.items() for r in range(runs)])


def table_rows(text: str) -> dict[str, list[str]]:
    """The rows of the markdown table in ``text`` by their first cell."""
    rows = [ln for ln in text.splitlines() if ln.startswith("| ") and not ln.startswith("| filter")]
    return {c[0]: c for c in ([x.strip() for x in ln.strip("|").split("|")] for ln in rows)}


def test_small_share_and_a_common_note():
    rng = np.random.default_rng(1)
    base = rng.uniform(0.09, 0.11, 12)
    # iae-ekf gains 0.5 % of what the oracle gains: printed "0.5 % [...]", not "0 % [0, 0]"
    m = frame({"ekf": lambda r: base[r], "iae-ekf": lambda r: base[r] - 0.0002,
               "ekf-oracle": lambda r: base[r] - 0.04})
    t = oracle_share(m, n_boot=200)
    r = t.iloc[0]
    assert 0.001 < r.share < 0.0095 and r.note == ""
    cell = table_rows(share_md(t, 200))["iae-ekf"][7]
    assert cell == f"{100 * r.share:.1f} % [{pct(r.share_lo)}, {pct(r.share_hi)}]" and cell.startswith("0.")
    # the oracle gains nothing (as on the IMU scenario): every row has the same reason, said once under the table
    m = frame({"ekf": lambda r: base[r], "anekf": lambda r: base[r] - 0.01, "iae-ekf": lambda r: base[r] - 0.02,
               "ekf-oracle": lambda r: base[r]})
    t = oracle_share(m, n_boot=200)
    assert list(t["filter"]) == ["anekf", "iae-ekf"] and len(set(t["note"])) == 1 and "not positive" in t["note"][0]
    text = share_md(t, 200)
    rows = table_rows(text)
    assert rows["anekf"][7] == rows["iae-ekf"][7] == "—"
    assert text.count(t["note"][0]) == 1 and text.endswith(f"\n\nEvery row: {t['note'][0]}.")
    # different notes stay in their rows
    one = share_md(t.iloc[:1], 200)
    assert f"— ({t['note'][0]})" in one and "Every row" not in one


# ----------------------------------------------------------------------------- item 4: shares near the threshold


def blocks(inside: dict, share: float = 0.8) -> pd.DataFrame:
    """A pooled block_consistency table: ``inside`` {(filter, block name): share inside}, the rest below."""
    rows = []
    for (f, name), v in inside.items():
        word = "consistent" if v >= share else "conservative"
        rows.append({"track": None, "filter": f, "kind": "ANEES", "item": name[:3], "name": name, "dof": 3,
                     "mean": 2.0, "inside": v, "above": 0.0, "below": 1 - v, "epochs": 1000, "word": word})
    out = pd.DataFrame(rows)
    out.attrs["share"] = share
    return out


def test_a_share_is_printed_on_its_words_side():
    """79.7 % inside is not consistent at 80 %: printed ``79.7 %``, never ``80 %`` (nor ``80.0 %``)."""
    assert share_text(0.797, 0.8) == "79.7 %" and share_text(0.7996, 0.8) == "79.9 %"
    assert share_text(0.79, 0.8) == "79 %" and share_text(0.8, 0.8) == "80 %" and share_text(0.8004, 0.8) == "80 %"
    assert share_text(0.195, 0.2) == "19.5 %" and share_text(0.195, 0.8) == "20 %"  # only near its own threshold
    assert share_text(0.8049, 0.805) == "80 %" and share_text(0.805, 0.805) == "80.5 %"  # a threshold of 80.5 %
    assert share_text(float("nan"), 0.8) == "—"
    t = blocks({("ekf", "velocity"): 0.797, ("ekf", "attitude"): 0.95, ("ukf", "velocity"): 0.62})
    assert consistency_words(t) == {"ekf": "conservative: velocity 79.7 %", "ukf": "conservative: velocity 62 %"}
    md = consistency_md(t)
    row = next(ln for ln in md.splitlines() if ln.startswith("| ekf | velocity"))
    assert "| 79.7 % |" in row and "| 20 % |" in row and row.rstrip(" |").endswith("conservative")
    # the verdict's consistency row: the best filter's worst block
    from nespm_cli.reports.verdict import VERDICT_COLUMNS, consistency_row
    from nespm_cli.reports.verdict_markdown import verdict_md

    vt = pd.DataFrame([consistency_row(t, ["ekf", "ukf"])], columns=list(VERDICT_COLUMNS))
    vt.attrs.update(consistent_share=0.8, any_lost=False)
    line = next(ln for ln in verdict_md(vt, pd.DataFrame(columns=["metric"])).splitlines() if "consistency" in ln)
    assert "`ekf` velocity 79.7 %" in line and "`ukf` velocity 62 %" in line and "80 %" not in line


# ----------------------------------------------------------------------------- item 5: the docs link


def link(text: str) -> str:
    """The target of the report's docs link (``<...>`` unwrapped)."""
    rest = text.split("[docs/report.md](", 1)[1]
    return rest[1:rest.index(">")] if rest.startswith("<") else rest.split(")", 1)[0]


def test_docs_link_holds_wherever_the_report_lands(tmp_path):
    """Outside the sources (pytest's /tmp) the link is the page's absolute path, so it holds after the folder
    is moved; inside them it is relative (a clone, a forge)."""
    assert REPORT_DOCS.is_file()
    out = tmp_path / "a" / "b"
    target = link(docs_line(out))
    assert target == REPORT_DOCS.as_posix() and Path(target).is_file()
    moved = tmp_path / "elsewhere" / "deeper" / "still"
    assert (moved / target).resolve() == REPORT_DOCS  # an absolute link does not depend on the folder
    inside = REPORT_DOCS.parents[1] / "results" / "some-study"
    rel = link(docs_line(inside))
    assert rel == "../../docs/report.md" and (inside / rel).resolve() == REPORT_DOCS
    assert link(docs_line(tmp_path / "with space")) == REPORT_DOCS.as_posix()


def test_a_written_report_links_to_the_page(tmp_path):
    """Through ``nespm report`` on a folder in /tmp, then copied elsewhere: the link still finds the page."""
    from test_reports_mc import noisy_metrics
    from nespm_cli.reports.dispatch import write_report

    noisy_metrics(12, {"ukf": 0.12, "anukf": 0.09}).to_parquet(tmp_path / "metrics.parquet")
    text = write_report(tmp_path, n_boot=50).read_text()
    copy = tmp_path.parent / f"{tmp_path.name}-copy" / "x"
    shutil.copytree(tmp_path, copy)
    assert (copy / link(text)).resolve() == REPORT_DOCS


# ----------------------------------------------------------------------------- item 6: the level and the limits


def test_leveled_factors_stay_within_the_limits():
    from nespm_cli.filters.options import SCALE_LIMITS
    from nespm_cli.tuning.objective import beyond_limits, leveled

    bases = {"acc_noise_scale": 1.0, "gyro_noise_scale": 1.0, "r_scale_dvl": 900.0}
    assert SCALE_LIMITS == (1e-3, 1e3)
    # a searched 900 (the --tune-range limit is 1e3) at a level c = 4 would be 1800; the base 900 too
    assert leveled({"acc_noise_scale": 900.0}, bases, 4.0) == {"acc_noise_scale": 1e3, "gyro_noise_scale": 2.0,
                                                               "r_scale_dvl": 1e3}
    assert beyond_limits({"acc_noise_scale": 900.0}, bases, 4.0) == {"acc_noise_scale": 1800.0, "r_scale_dvl": 1800.0}
    # a searched 0.1 (the default range's low end) at c = 1e-6 would be 1e-4
    assert leveled({"gyro_noise_scale": 0.1}, {"gyro_noise_scale": 1.0}, 1e-6) == {"gyro_noise_scale": 1e-3}
    assert beyond_limits({"gyro_noise_scale": 0.1}, {"gyro_noise_scale": 1.0}, 1e-6) == pytest.approx(
        {"gyro_noise_scale": 1e-4})
    assert beyond_limits({"acc_noise_scale": 3.0}, {"acc_noise_scale": 1.0}, 4.0) == {}


def test_tune_writes_a_tuned_toml_mc_reads(tmp_path):
    """A real (tiny) tune whose search sits near the low limit and whose study's R is 30x (conservative: the level
    c < 1): gyro_noise_scale x √c falls below 1e-3. It is written at 1e-3 with a comment, the report's values table
    says "clipped", and ``nespm mc --config tuned.toml`` runs (before, the value was written as is and mc refused
    it: "a noise scale is a factor from 0.001 to 1000")."""
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+

    from nespm_cli.experiments.spec import Spec
    from nespm_cli.tuning.run import run_tune
    from nespm_cli.tuning.spec import TuneSpec

    t = TuneSpec(Spec(tracks=(5,), runs=2, filters=("ekf",), dvl="synthetic", window="0:30",
                      filter_options=(("ekf", "r_scale_dvl", 30.0),)),
                 trials=2, profile=False, level_runs=2, refine_trials=0,
                 ranges=(("ekf", "gyro_noise_scale", 0.001, 0.0011), ("ekf", "r_scale_dvl", None, None)))
    out = tmp_path / "tune"
    b = run_tune(t, out)["best"]["ekf"]
    raw = b["shape"]["gyro_noise_scale"] * np.sqrt(b["level"])
    assert b["level"] < 0.8 and raw < 1e-3, (b["level"], raw)  # the premise: the level pushes it past the limit
    assert b["values"]["gyro_noise_scale"] == 1e-3
    text = (out / "tuned.toml").read_text()
    assert tomllib.loads(text)["filters"]["ekf"]["gyro_noise_scale"] == 1e-3
    assert f"# ekf.gyro_noise_scale: {raw:.6g} at the level, outside the noise-scale limits 0.001 to 1000" in text
    rc, _, err = nespm("report", out, "--no-progress")
    assert rc == 0, err
    row = next(ln for ln in (out / "report.md").read_text().splitlines() if ln.startswith("| ekf | gyro_noise_scale"))
    assert "0.001 (clipped: " in row and "at the level)" in row
    rc, _, err = nespm("mc", "--config", out / "tuned.toml", "--tracks", "5", "--runs", "1", "--window", "0:20",
                       "--dvl", "synthetic", "--filters", "ekf", "--jobs", "1", "--no-progress", "--out", tmp_path / "mc")
    assert rc == 0, err


def test_consistency_legends_print_a_share_on_its_words_side(tmp_path, monkeypatch):
    """The ANEES figure's legend: 797 of the 999 epochs after t = 0 inside (79.8 %) reads ``79.7 % inside``
    (the tables' rule at the 80 % threshold: rounded away from it), not ``80 % inside``; 949 of 999 reads
    ``95 % inside``."""
    from nespm_cli.reports import consistency as cons
    from nespm_cli.reports.figures import filter_colors, use_agg

    use_agg()
    n, labels = 1000, []
    t = np.arange(n, dtype=float)
    frames = []
    for f, k in (("ekf", 798), ("ukf", 950)):
        x = np.where(np.arange(n) < k, 3.0, 100.0)
        frames.append(pd.DataFrame({"filter": f, "track": 5, "epoch": np.arange(n), "t": t, "n_runs": 20,
                                    "nees_vel_mean": x, "nees_att_mean": x}))
    ep = pd.concat(frames, ignore_index=True)
    real = cons.save_figure

    def keep(fig, path):
        for ax in fig.axes:
            labels.extend(ax.get_legend_handles_labels()[1])
        return real(fig, path)

    monkeypatch.setattr(cons, "save_figure", keep)
    cons.anees_drawn(ep, ["ekf", "ukf"], filter_colors(("ekf", "ukf")), "ANEES", tmp_path / "a.png")
    assert "ekf (79.7 % inside)" in labels and "ukf (95 % inside)" in labels, labels
