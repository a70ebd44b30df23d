"""``nespm_cli.api.oracle_share`` (docs/api.md, docs/adapting.md): the mc report's "Share of the oracle's
gain" table as a DataFrame, with the report's numbers. A tiny study: embedded track 5, 0-60 s, 6 runs, a
x4 DVL-noise step at 30 s, the fixed EKF, the IAE adaptive-R EKF and the EKF told the true noise."""
from __future__ import annotations

import numpy as np
import pytest

import nespm_cli.api as nespm
from conftest import cli
from nespm_cli.reports.markdown import fmt
from nespm_cli.reports.mc_markdown import ORACLE_SECTION
from nespm_cli.reports.oracle_share import pct, share_md

pytestmark = pytest.mark.usefixtures("no_env_data_dir")
N_BOOT = 200


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """The tiny mc folder with its report (``--n-boot 200``)."""
    from nespm_cli.cli import main  # capsys is function-scoped: the module's folder is made by main directly

    out = tmp_path_factory.mktemp("oracle") / "adapt"
    rc = main(["mc", "--tracks", "5", "--runs", "6", "--window", "0:60", "--dvl", "synthetic", "--no-progress",
               "--jobs", "1", "--filters", "ekf,iae-ekf,ekf-oracle",
               "--sensor-option", "dvl.noise_schedule=step:0=1,30=4", "--out", str(out)])
    assert rc == 0
    assert main(["report", str(out), "--n-boot", str(N_BOOT)]) == 0
    return out


def section(text: str) -> str:
    """The body of the report's oracle section."""
    body = text.split(ORACLE_SECTION + "\n\n", 1)[1]
    return body.split("\n## ", 1)[0].strip()


def test_api_share_is_the_reports(folder):
    """The API's table renders to the report's section character for character, and its row's numbers
    are those printed: VRMSE of the fixed, adaptive and oracle EKF and the share."""
    t = nespm.oracle_share(folder, n_boot=N_BOOT)
    assert list(t[["filter", "base", "oracle"]].itertuples(index=False, name=None)) == [
        ("iae-ekf", "ekf", "ekf-oracle")]
    text = (folder / "report.md").read_text()
    assert section(text) == share_md(t, N_BOOT).strip()
    r = t.iloc[0]
    line = next(ln for ln in text.splitlines() if ln.startswith("| iae-ekf | ekf | ekf-oracle |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[3:6] == [fmt(r.base_value), fmt(r.filter_value), fmt(r.oracle_value)]
    # the step makes the oracle gain clearly (measured: about 20 % of the fixed EKF's VRMSE), so a share exists
    assert r.oracle_gain_lo > 0 and np.isfinite(r.share) and r.share_lo <= r.share <= r.share_hi
    assert cells[7].startswith(f"{pct(r.share)} % [")  # whole percent, one decimal below 1 %
    assert r.pairs_min == 6 and "not trusted" in r.note  # 6 < 10 runs: said, not hidden
    # report_tables carries the same table
    tables = nespm.report_tables(folder, n_boot=N_BOOT)
    assert tables["oracle_share"].equals(t)


def test_api_share_refuses_in_one_line(folder, tmp_path, capsys):
    """No oracle among the filters, not a results folder, a bad metric: one-line NespmError."""
    rc, _, err = cli(capsys, "mc", "--tracks", "5", "--runs", "2", "--window", "0:20", "--no-progress", "--jobs",
                     "1", "--filters", "ekf", "--out", tmp_path / "plain")
    assert rc == 0, err
    for call, words in ((lambda: nespm.oracle_share(tmp_path / "plain"), "no oracle among the filters (ekf)"),
                        (lambda: nespm.oracle_share(tmp_path / "none"), "none"),
                        (lambda: nespm.oracle_share(folder, metric="nees"), "metric must be one of")):
        with pytest.raises(nespm.NespmError) as e:
            call()
        assert words in str(e.value) and "\n" not in str(e.value)
    assert "oracle_share" not in nespm.report_tables(tmp_path / "plain", n_boot=50)
