"""``corruption.imu_errors(real, t, clean=(f_b, w_ib_b))``: the corrupted IMU formed in the error rows
(issue 41 item 2), bit for bit what ``f_b + e_f``, ``w_ib_b + e_w`` gave, never cached, and the cached
errors of an earlier call untouched; ``mc`` through it gives the metrics and epochs of the old path. The
errors themselves are those of the code before (the constant schedule's product by factors of 1 skipped,
the arrays allocated without NumPy's huge-page advice: neither changes a value).
"""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from conftest import nespm
from nespm_cli.data import corruption
from nespm_cli.data.corruption import STREAM_ACC, STREAM_GYRO, CorruptionConfig, draw, imu_errors, segment_index, stream
from nespm_cli.experiments import mc

T = np.arange(0, 60.0 + 1e-9, 0.01)  # 60 s of 100 Hz samples: 3 segments of 20 s
M = len(T) - 1

CONFIGS = [CorruptionConfig(), CorruptionConfig(schedule="dynamic", dynamic_bias="run"),
           CorruptionConfig(schedule="dynamic", dynamic_bias="segment")]


def clean_imu(seed=0):
    """A clean IMU of the vehicles' magnitudes (gravity plus manoeuvres; earth rate plus turns) whose
    sums with the errors round in the last bit."""
    g = np.random.default_rng(seed)
    f_b = np.array([0.0, 0.0, -9.81]) + 0.3 * g.standard_normal((M, 3))
    w_b = 7.29e-5 + 0.02 * g.standard_normal((M, 3))
    return f_b, w_b


def realization(cfg, runs=np.arange(3, 8)):
    return draw(11, 5, runs, float(T[-1] - T[0]), cfg)


def reference_errors(real, t):
    """``imu_errors`` as it was before (bd64481): every run's rows std x N(0, 1), times the segment
    factors, plus bias x factor, in this order, with no pass skipped."""
    M, S = len(t) - 1, real.acc_factors.shape[1]
    seg = segment_index(t[1:] - t[0], real.config.segment_s, S)
    bias_seg = seg if real.config.dynamic_bias == "segment" else np.zeros(1, dtype=np.int64)
    out = []
    for kind, std, factors, bias in ((STREAM_ACC, real.config.acc_noise, real.acc_factors, real.b_a),
                                     (STREAM_GYRO, real.config.gyro_noise, real.gyro_factors, real.b_g)):
        e = np.empty((len(real.runs), M, 3))
        for i, r in enumerate(real.runs):
            n = e[i]
            stream(real.seed, real.track, int(r), kind).standard_normal((M, 3), out=n)
            n *= std
            n *= factors[i, seg][:, None]
            n += factors[i, bias_seg][:, None] * bias[i]
        out.append(e)
    return tuple(out)


@pytest.mark.parametrize("cfg", CONFIGS, ids=["constant", "dynamic-run", "dynamic-segment"])
def test_errors_are_those_of_before(cfg):
    """The errors alone (the constant schedule now skips its product by factors of 1) and the corrupted
    IMU, against the code before the change."""
    f_b, w_b = clean_imu(2)
    ref_f, ref_w = reference_errors(realization(cfg), T)
    e_f, e_w = imu_errors(realization(cfg), T)
    assert np.array_equal(e_f, ref_f) and np.array_equal(e_w, ref_w)
    f, w = imu_errors(realization(cfg), T, clean=(f_b, w_b))
    assert np.array_equal(f, f_b + ref_f) and np.array_equal(w, w_b + ref_w)


@pytest.mark.parametrize("cfg", CONFIGS, ids=["constant", "dynamic-run", "dynamic-segment"])
def test_clean_gives_the_same_bits_as_clean_plus_errors(cfg):
    f_b, w_b = clean_imu()
    e_f, e_w = imu_errors(realization(cfg), T)
    f, w = imu_errors(realization(cfg), T, clean=(f_b, w_b))
    want_f, want_w = f_b + e_f, w_b + e_w  # the old expression of mc.realization_inputs
    assert f.shape == w.shape == (5, M, 3)
    assert np.array_equal(f, want_f) and np.array_equal(w, want_w)
    # the test is not vacuous: the sums do round (adding and subtracting the clean part changes bits)
    assert not np.array_equal(f - f_b, e_f)


def test_a_call_with_clean_is_not_cached_and_leaves_the_cache_alone():
    f_b, w_b = clean_imu(1)
    real = realization(CONFIGS[1])
    f, w = imu_errors(real, T, clean=(f_b, w_b))
    assert real._cache == {}  # the corrupted IMU is never cached
    e_f, e_w = imu_errors(real, T)  # now the errors, drawn afresh and cached
    assert np.array_equal(f, f_b + e_f) and np.array_equal(w, w_b + e_w)
    keep_f, keep_w = e_f.copy(), e_w.copy()
    f2, w2 = imu_errors(real, T, clean=(f_b, w_b))  # from the cache: read, not written
    assert f2 is not e_f and w2 is not e_w
    assert not np.shares_memory(f2, e_f) and not np.shares_memory(w2, e_w)
    assert np.array_equal(e_f, keep_f) and np.array_equal(e_w, keep_w)
    cached_f, cached_w = imu_errors(real, T)
    assert cached_f is e_f and np.array_equal(cached_f, keep_f) and np.array_equal(cached_w, keep_w)
    assert np.array_equal(f2, f) and np.array_equal(w2, w)
    f_b_before = f_b.copy()
    imu_errors(realization(CONFIGS[0]), T, clean=(f_b, w_b))
    assert np.array_equal(f_b, f_b_before)  # the clean arrays are read only


def test_clean_of_the_wrong_shape_is_refused():
    f_b, w_b = clean_imu()
    with pytest.raises(ValueError, match="clean arrays"):
        imu_errors(realization(CONFIGS[0]), T, clean=(f_b[:-1], w_b))


def old_imu_errors(real, t, clean=None):
    """The path before: the errors (cached), then ``clean + errors`` in new arrays."""
    old_imu_errors.calls += 1
    e_f, e_w = corruption.imu_errors(real, t)
    return (e_f, e_w) if clean is None else (clean[0] + e_f, clean[1] + e_w)


old_imu_errors.calls = 0


def run_mc(argv, out):
    rc, stdout, stderr = nespm(*argv, "--out", out)
    assert rc == 0, stderr
    return {name: pd.read_parquet(out / f"{name}.parquet") for name in ("metrics", "epochs")}


def comparable(df: pd.DataFrame) -> pd.DataFrame:
    """Without the timing columns (seconds differ between any two runs)."""
    return df.drop(columns=[c for c in df.columns if "second" in c.lower() or c.lower().endswith("_s")])


@pytest.mark.usefixtures("no_env_data_dir")
@pytest.mark.parametrize("schedule", ["constant", "dynamic"])
def test_mc_metrics_are_those_of_the_old_path(short_data_dir, tmp_path, monkeypatch, schedule):
    argv = ["mc", "--tracks", "5", "--runs", "3", "--filters", "ekf,ukf-nespm", "--jobs", "1",
            "--data-dir", str(short_data_dir), "--schedule", schedule, "--no-progress"]
    new = run_mc(argv, tmp_path / "new")
    monkeypatch.setattr(mc, "imu_errors", old_imu_errors)
    calls = old_imu_errors.calls
    old = run_mc(argv, tmp_path / "old")
    assert old_imu_errors.calls > calls  # the old path ran here (one process: --jobs 1)
    for name in ("metrics", "epochs"):
        a, b = comparable(new[name]), comparable(old[name])
        assert len(a) > 0 and list(a.columns) == list(b.columns)
        pd.testing.assert_frame_equal(a, b, check_exact=True)


def test_small_pages_leave_numpys_setting_as_it_was():
    toggle = np._core.multiarray._set_madvise_hugepage
    for setting in (True, False):
        before = toggle(setting)
        try:
            arrays = corruption.empty_small_pages((2, 5, 3), 2)
            assert toggle(setting) is setting  # restored (the call returns the setting it replaces)
        finally:
            toggle(before)
        assert len(arrays) == 2 and all(a.shape == (2, 5, 3) and a.dtype == float for a in arrays)
        assert not np.shares_memory(arrays[0], arrays[1])
