"""Filter plugins (nespm_cli.filters.registry, docs/plugins.md) and the worked CKF example.

The CKF of examples/ckf_filter.py is loaded by path and run through ``run_filter`` (via
``experiments.mc.simulate``, the same inputs for every filter) beside the EKF on the short
embedded track 5 (``short_data_dir``, 80 epochs): with the papers' protocol errors the model
is nearly linear over the error spread, so the CKF's VRMSE agrees with the EKF's within 1 %.
Bad plugin files fail with one-line NespmErrors naming the file; a built-in's name is refused.

Cost: ~10 s (two filters over 80 epochs, 4 runs).
"""
from __future__ import annotations

import dataclasses
import os
import textwrap
from pathlib import Path

import numpy as np
import pytest

from nespm_cli.errors import NespmError
from nespm_cli.experiments.metrics import run_metrics
from nespm_cli.experiments.mc import simulate
from nespm_cli.experiments.spec import Spec
from nespm_cli.filters import FILTERS, FilterConfig, initial_nav, run_filter
from nespm_cli.filters.ekf import EKF
from nespm_cli.filters.protocol import ErrorStateFilter, Filter
from nespm_cli.filters.registry import (filter_names, get_filter, is_builtin, load_plugin, register,
                                        register_filter)

REPO = Path(__file__).resolve().parents[1]
CKF = REPO / "examples" / "ckf_filter.py"
TRACK, RUNS = 5, 4


@pytest.fixture(scope="module")
def ckf_module():
    return load_plugin(CKF)


@pytest.fixture(scope="module")
def side_by_side(ckf_module, short_data_dir):
    spec = Spec(tracks=(TRACK,), runs=RUNS, dvl="synthetic", data_dir=str(short_data_dir))
    res, truth, _ = simulate(spec, TRACK, np.arange(RUNS), ("ekf", "ckf-example", "ukf"))
    return res


def write(tmp_path: Path, name: str, body: str) -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(body))
    return p


def one_line(e: pytest.ExceptionInfo) -> str:
    msg = str(e.value)
    assert "\n" not in msg, msg
    return msg


# --- the example --------------------------------------------------------------------------

def test_ckf_example_registers(ckf_module):
    cls = get_filter("ckf-example")
    assert cls is ckf_module.CubatureKF and cls.name == "ckf-example"
    assert issubclass(cls, Filter) and cls.has_covariance and not cls.needs_noise_std
    assert "ckf-example" in filter_names() and not is_builtin("ckf-example")
    assert "ckf-example" not in FILTERS  # FILTERS: the built-ins only


def test_ckf_example_uses_only_the_public_protocol():
    src = CKF.read_text()
    imports = [ln.split()[1] for ln in src.splitlines() if ln.startswith(("from nespm_cli", "import nespm_cli"))]
    assert sorted(imports) == ["nespm_cli.filters.protocol", "nespm_cli.filters.registry", "nespm_cli.sensors"]
    assert "import _" not in src and ", _" not in src


def test_load_plugin_is_idempotent(ckf_module):
    assert load_plugin(CKF) is ckf_module
    assert load_plugin(os.path.relpath(CKF)) is ckf_module  # the same file by another spelling
    # the same class registered again (a worker importing the plugin again) is harmless
    register_filter("ckf-example", ckf_module.CubatureKF)
    assert get_filter("ckf-example") is ckf_module.CubatureKF


def test_ckf_agrees_with_ekf_within_one_percent(side_by_side):
    vr = {k: run_metrics(err, out.diverged)["vrmse"] for k, (out, err, _) in side_by_side.items()}
    for k, (out, _, _) in side_by_side.items():
        assert not out.diverged.any(), k
        assert out.dvl_used[:, 1:].all(), k
    rel = np.abs(vr["ckf-example"] - vr["ekf"]) / vr["ekf"]
    print("VRMSE ekf", vr["ekf"], "ckf", vr["ckf-example"], "ukf", vr["ukf"], "rel ckf-ekf", rel)
    assert (rel < 0.01).all(), rel
    ekf, ckf = side_by_side["ekf"][0], side_by_side["ckf-example"][0]
    assert np.isfinite(ckf.P_diag).all() and (ckf.P_diag > 0).all()
    # a linear prediction: the covariances agree closely too (relative, every epoch and state)
    assert np.max(np.abs(ckf.P_diag - ekf.P_diag) / ekf.P_diag) < 0.01


def test_ckf_example_runs_with_time_update_imu(ckf_module):
    """run_filter directly, per-IMU-step time update, on a tiny hand-made batch."""


    R, M = 2, 20
    pos = np.array([0.5, 0.6, -10.0])
    C = np.eye(3)
    v = np.array([1.0, 0.0, 0.0])
    g = 9.80
    f = np.broadcast_to([0.0, 0.0, -g], (R, M, 3)).copy()
    w = np.zeros((R, M, 3))
    dt = np.full(M, 0.01)
    e = np.array([0, 10, 20])
    dvl = np.broadcast_to(v, (R, 3, 3)).copy()
    mask = np.array([False, True, True])
    nav0 = initial_nav(pos, np.broadcast_to(v, (R, 3)), C, np.zeros((R, 3)), np.zeros((R, 3)))
    for mode in ("dvl", "imu"):
        cfg = dataclasses.replace(FilterConfig(), time_update=mode)
        out = run_filter("ckf-example", cfg, f, w, dt, e, dvl, mask, nav0)
        assert out.pos.shape == (R, 3, 3) and np.isfinite(out.P_diag).all() and not out.diverged.any()


# --- bad plugins -----------------------------------------------------------------------------

def test_missing_file(tmp_path):
    p = tmp_path / "nope.py"
    with pytest.raises(NespmError) as e:
        load_plugin(p)
    assert str(p) in one_line(e) and "no such file" in str(e.value)


def test_syntax_error(tmp_path):
    p = write(tmp_path, "broken.py", "def f(:\n    pass\n")
    with pytest.raises(NespmError) as e:
        load_plugin(p)
    assert str(p) in one_line(e) and "SyntaxError" in str(e.value)


def test_import_error(tmp_path):
    p = write(tmp_path, "raises.py", """
        import numpy
        raise RuntimeError("boom\\nsecond line")
        """)
    with pytest.raises(NespmError) as e:
        load_plugin(p)
    assert str(p) in one_line(e) and "RuntimeError" in str(e.value) and "boom" in str(e.value)


def test_registers_nothing(tmp_path):
    p = write(tmp_path, "empty.py", "X = 1\n")
    with pytest.raises(NespmError) as e:
        load_plugin(p)
    assert str(p) in one_line(e) and "registers no filter" in str(e.value)


def test_unknown_module_name():
    with pytest.raises(NespmError) as e:
        load_plugin("no_such_module_for_nespm")
    assert "no_such_module_for_nespm" in one_line(e)


def test_name_clash_with_builtin_is_refused(tmp_path):
    p = write(tmp_path, "clash.py", """
        from nespm_cli.filters.protocol import ErrorStateFilter
        from nespm_cli.filters.registry import register

        @register("ok-before-clash")
        class Fine(ErrorStateFilter):
            pass

        @register("ekf")
        class Mine(ErrorStateFilter):
            pass
        """)
    with pytest.raises(NespmError) as e:
        load_plugin(p)
    msg = one_line(e)
    assert str(p) in msg and "'ekf'" in msg and "built-in" in msg
    assert get_filter("ekf") is EKF and is_builtin("ekf")
    assert "ok-before-clash" not in filter_names()  # a failed plugin leaves nothing registered


def test_name_clash_between_plugins(tmp_path):
    body = """
        from nespm_cli.filters.ekf import EKF
        from nespm_cli.filters.registry import register

        @register("twin-name")
        class Twin(EKF):
            pass
        """
    a = write(tmp_path, "a.py", body)
    b = write(tmp_path, "b.py", body)
    load_plugin(a)
    with pytest.raises(NespmError) as e:
        load_plugin(b)
    assert str(b) in one_line(e) and "already registered" in str(e.value)


def test_register_rejects_non_filters():
    with pytest.raises(NespmError):
        register("not-a-filter")(object)
    with pytest.raises(NespmError):
        register_filter("bad name", ErrorStateFilter)


def test_unknown_filter_lists_names():
    with pytest.raises(NespmError) as e:
        get_filter("nope")
    assert "unknown filter 'nope'" in one_line(e) and "ekf" in str(e.value)


def test_ckf_plugin_runs_through_mc_and_report_like_a_builtin(short_data_dir, tmp_path):
    """--filter-plugin: the parent and every loky worker load the file; the CKF sees the
    EKF's realizations; the report has its row; the manifest records the plugin path."""
    import json

    import pandas as pd

    from conftest import nespm

    out = tmp_path / "plug"
    rc, stdout, stderr = nespm("mc", "--tracks", "5", "--runs", "4", "--chunk-size", "2", "--jobs", "2",
                               "--filters", "ekf,ckf-example", "--filter-plugin", CKF, "--dvl", "synthetic",
                               "--data-dir", short_data_dir, "--no-progress", "--out", out)
    assert rc == 0, stderr
    m = pd.read_parquet(out / "metrics.parquet")
    assert sorted(m["filter"].unique()) == ["ckf-example", "ekf"] and not m["diverged"].any()
    v = m.pivot(index="run", columns="filter", values="vrmse")
    np.testing.assert_allclose(v["ckf-example"], v["ekf"], rtol=0.01)  # linear regime: within 1 %
    assert json.loads((out / "manifest.json").read_text())["options"]["filter_plugins"] == [str(CKF.resolve())]
    rc, report, stderr = nespm("report", out)
    assert rc == 0, stderr
    assert "| ckf-example |" in report or "`ckf-example`" in report
