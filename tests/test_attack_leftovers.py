"""The attack's leftovers (issue 39): each bad input ends in one line naming the option, key or file,
exit code 2, and nothing in ``--out``; and the newcomer's rough edges (the tune interrupt line, the
report's summary, tuned.toml's plugins, the help's filter lists, the sweep's horizontal-error rows).
Short runs of embedded track 5 (``--window 0:60``, 2 runs)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from nespm_cli.cli.messages import INTERRUPTED, interrupted
from nespm_cli.cli.result_commands import report_summary
from nespm_cli.cli.tune_command import plugin_words
from nespm_cli.experiments.spec import Spec
from nespm_cli.filters import FILTERS
from nespm_cli.tuning.best import plugin_lines

from conftest import assert_one_error_line, nespm, write_short_tracks

pytestmark = pytest.mark.usefixtures("no_env_data_dir")

SHORT = ("--tracks", "5", "--window", "0:60", "--runs", "2", "--no-progress", "--jobs", "1")


def refused(out: Path, *argv, needles=()) -> str:
    """``nespm argv... --out out``: one line holding ``needles``, exit 2, ``out`` not created."""
    rc, so, err = nespm(*argv, "--out", out)
    line = assert_one_error_line(rc, so, err, *needles)
    assert not out.exists(), sorted(p.name for p in out.iterdir())  # no .lock, chunks/, manifest.json
    return line


@pytest.fixture(scope="module")
def mc_folder(tmp_path_factory) -> Path:
    """A finished short mc folder (ekf and ukf, 2 runs)."""
    out = tmp_path_factory.mktemp("mc") / "mc"
    rc, _, err = nespm("mc", "--filters", "ekf,ukf", *SHORT, "--out", out)
    assert rc == 0, err
    return out


def listing(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# ----------------------------------------------------------------------------- filter options


@pytest.mark.parametrize("option, needles", [
    ("iae-ekf.window=1e-9", ["--filter-option iae-ekf.window=1e-09", "measurement epoch", "2 innovations"]),
    ("iae-ekf.window=1", ["--filter-option iae-ekf.window=1:", "1.00251 s"]),  # one DVL epoch: one innovation
    ("ekf.acc_noise_scale=1e300", ["--filter-option ekf.acc_noise_scale", "from 0.001 to 1000"]),
    ("ekf.r_scale_dvl=1e-9", ["--filter-option ekf.r_scale_dvl", "from 0.001 to 1000"]),
    ("ukf.kappa=-20", ["--filter-option ukf.kappa=-20", "kappa > -12"]),
    ("ukf.beta=-5", ["--filter-option ukf.beta", "from 0 to 1000"]),
    ("vb-ekf.iterations=100000", ["--filter-option vb-ekf.iterations", "from 1 to 100"]),
])
def test_a_filter_option_out_of_its_range_is_refused_before_anything_is_written(tmp_path, option, needles):
    name = option.split(".")[0]
    refused(tmp_path / "out", "mc", "--filters", name, "--filter-option", option, *SHORT, needles=needles)


def test_a_window_of_two_innovations_runs(tmp_path):
    """The bound is one epoch step (1.0025 s on track 5): a 1.5 s window holds two innovations and runs."""
    rc, _, err = nespm("mc", "--filters", "iae-ekf", "--filter-option", "iae-ekf.window=1.5", *SHORT,
                       "--out", tmp_path / "out")
    assert rc == 0, err


def test_a_config_noise_scale_of_1e300_names_the_key(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[filters.ekf]\nacc_noise_scale = 1e300\n")
    refused(tmp_path / "out", "mc", "--config", cfg, *SHORT, needles=["ekf.acc_noise_scale", "1e+300"])


@pytest.mark.parametrize("flag, value", [("--filter-acc-noise", "1e300"), ("--filter-gyro-noise", "5"),
                                         ("--acc-bias-rw", "1e10"), ("--dvl-r-std", "100")])
def test_a_filter_noise_value_beyond_a_sensor_is_refused(tmp_path, flag, value):
    refused(tmp_path / "out", "mc", "--filters", "ekf", flag, value, *SHORT, needles=[flag, "units mistake"])


def test_a_duplicate_filter_is_named(tmp_path):
    line = refused(tmp_path / "out", "mc", "--filters", "ekf,ukf,ekf", *SHORT, needles=["--filters", "ekf is given 2 times"])
    assert "ukf is given" not in line


# ----------------------------------------------------------------------------- --jobs, folders of another kind


@pytest.mark.parametrize("command", [["mc", "--filters", "ekf"], ["tune", "--filters", "ekf", "--trials", "2"],
                                     ["sweep", "--filters", "ekf", "--param", "acc-noise", "--values", "0.01"]])
def test_jobs_0_is_one_rule(tmp_path, command):
    rc, so, err = nespm(*command, *SHORT[:-2], "--jobs", "0", "--out", tmp_path / "out")
    assert assert_one_error_line(rc, so, err).endswith("--jobs must be at least 1, got 0")
    assert not (tmp_path / "out").exists()


def test_tune_into_an_mc_folder_is_refused(mc_folder):
    before = listing(mc_folder)
    rc, so, err = nespm("tune", "--filters", "ekf", "--trials", "2", *SHORT, "--out", mc_folder)
    assert_one_error_line(rc, so, err, f"--out {mc_folder}", "results of nespm mc, sweep or gp-ukf (manifest.json)",
                          "new --out folder")
    assert listing(mc_folder) == before


@pytest.mark.parametrize("held", ["tune.json", "study.journal", "study.db"])
@pytest.mark.parametrize("command", [["mc"], ["sweep", "--param", "acc-noise", "--values", "0.01"]])
def test_mc_or_sweep_into_a_tune_folder_is_refused(tmp_path, held, command):
    out = tmp_path / "tune"
    out.mkdir()
    (out / held).write_text("{}")
    rc, so, err = nespm(*command, "--filters", "ekf", *SHORT, "--out", out)
    assert_one_error_line(rc, so, err, f"--out {out}", f"a nespm tune study ({held})", "new --out folder")
    assert sorted(p.name for p in out.iterdir()) == [held]  # no .lock, chunks/, manifest.json


# ----------------------------------------------------------------------------- a DEPTH symlink loop


def test_a_depth_file_that_is_a_symlink_loop_is_named(tmp_path):
    data = write_short_tracks(tmp_path / "data", numbers=(5,), epochs=61)
    depth = data / "Trajectory5" / "DEPTH_trajectory5.csv"
    os.symlink(depth.name, depth)  # points at itself
    refused(tmp_path / "out", "mc", "--data-dir", data, "--tracks", "5", "--runs", "2", "--filters", "ekf",
            "--state", "15", "--sensors", "dvl,depth", "--no-progress", needles=[str(depth), "symbolic link loop"])
    depth.unlink()
    os.symlink("nowhere.csv", depth)  # a dangling link: named too, not "no depth file"
    refused(tmp_path / "out", "mc", "--data-dir", data, "--tracks", "5", "--runs", "2", "--filters", "ekf",
            "--state", "15", "--sensors", "dvl,depth", "--no-progress",
            needles=[str(depth), "symbolic link to nowhere.csv, which does not exist"])


# ----------------------------------------------------------------------------- the newcomer's rough edges


def test_the_interrupt_line_speaks_of_the_commands_unit():
    line = interrupted(["tune", "--filters", "ekf", "--out", "res/t"])
    assert "trials" in line and "res/t/study.journal" in line and "continue the study" in line and "chunk " not in line
    assert "--storage database" in interrupted(["tune", "--storage", "sqlite:///x.db"])
    assert "results/tune/study.journal" in interrupted(["tune"])
    assert interrupted(["mc", "--out", "x"]) == INTERRUPTED and "chunks" in INTERRUPTED


def test_report_prints_the_verdict_and_the_path_not_the_whole_report(mc_folder):
    rc, so, err = nespm("report", mc_folder, "--n-boot", "50", "--no-progress")
    assert rc == 0, err
    text = (mc_folder / "report.md").read_text()
    lines = so.splitlines()
    assert len(text.splitlines()) > 80 and len(lines) <= 8, lines
    assert lines[0] == "nespm Monte Carlo report: verdict"
    assert any(x.startswith("  velocity RMSE [m/s]: `") and " vs `" in x for x in lines)
    assert any(x.startswith("  horizontal position error, final [m]:") for x in lines)
    assert lines[-1].startswith(f"wrote {mc_folder / 'report.md'} (") and "--print" in lines[-1]
    rc, so, err = nespm("report", mc_folder, "--n-boot", "50", "--no-progress", "--print")
    assert rc == 0, err
    assert so == text + "\n" + f"wrote {mc_folder / 'report.md'}\n"


def test_a_report_without_a_verdict_gives_its_first_paragraph():
    text = "# Tuning report\n\nEvery filter searched.\nWith the same budget.\n\n## Training scores\n\n| a | b |\n"
    assert report_summary(text) == ["Tuning report", "Every filter searched. With the same budget."]


def test_tuned_toml_records_the_plugins_and_the_next_command_loads_them(tmp_path):
    spec = Spec(sensor_plugins=("/p/usbl.py",), filter_plugins=("my.filters",))
    assert plugin_lines(spec) == ['filter_plugin = ["my.filters"]', 'sensor_plugin = ["/p/usbl.py"]', ""]
    assert plugin_lines(Spec()) == []
    toml = tmp_path / "tuned.toml"
    toml.write_text("[filters.ekf]\nacc_noise_scale = 2.0\n")  # a file that does not record them
    assert plugin_words(spec, toml) == " --filter-plugin my.filters --sensor-plugin /p/usbl.py"
    toml.write_text("\n".join(plugin_lines(spec)) + "[filters.ekf]\nacc_noise_scale = 2.0\n")
    assert plugin_words(spec, toml) == ""


@pytest.mark.parametrize("argv", [["mc", "--help"], ["run", "--help"], ["sweep", "--help"]])
def test_the_help_lists_every_built_in_filter(argv):
    rc, so, _ = nespm(*argv)
    assert rc == 0
    flat = " ".join(so.split()).replace("- ", "-")  # the help wraps lines, sometimes inside a name
    assert all(f in flat for f in FILTERS) and "aq-ekf" in flat


def test_the_python_sweep_tables_have_the_reports_horizontal_error_rows(tmp_path):
    from nespm_cli.api import report_tables

    out = tmp_path / "sweep"
    rc, _, err = nespm("sweep", "--filters", "ekf,ukf", "--param", "acc-noise", "--values", "0.02,0.04", *SHORT,
                       "--out", out)
    assert rc == 0, err
    t = report_tables(out, n_boot=50)
    v = t["verdict"]
    assert sorted(set(v["metric"])) == ["anees", "hpe", "hpe_final", "mrmse", "vrmse"]
    assert sorted(set(v["value"])) == [0.02, 0.04]
    h = t["horizontal"]
    avg = h[h["track"].isna()]
    assert list(avg["value"]) == [0.02, 0.02, 0.04, 0.04] and list(avg["filter"]) == ["ekf", "ukf"] * 2
    assert (avg["hpe_final"] > 0).all() and (avg["cep50"] > 0).all()
    rc, so, err = nespm("report", out, "--n-boot", "50", "--no-progress")
    assert rc == 0, err
    md = (out / "report.md").read_text()
    for r in v[v["metric"] == "hpe_final"].itertuples():  # the same numbers as the report's verdict rows
        assert f"`{r.best}` {r.best_value:.4g}" in md
