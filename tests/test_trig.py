"""The latitude's sine and cosine (nav.trig.sin_cos): its constants, its accuracy against the C library,
NaN beyond its domain without a warning, and the same bits compiled as in NumPy."""
from __future__ import annotations

import math
import struct
import warnings
from decimal import Decimal, getcontext

import numpy as np
import pytest

from nespm_cli.nav import trig

PI_50 = Decimal("3.14159265358979323846264338327950288419716939937510")


def ulps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|a − b| in units of b's last place."""
    return np.abs(a - b) / np.spacing(np.abs(b))


def test_constants_split_pi_over_2():
    getcontext().prec = 60
    bits = struct.unpack("<Q", struct.pack("<d", trig.PIO2_HI))[0]
    assert bits & ((1 << 20) - 1) == 0  # 33 significant bits: k · PIO2_HI exact
    rest = PI_50 / 2 - Decimal(trig.PIO2_HI) - Decimal(trig.PIO2_LO)
    assert abs(rest) < Decimal("1e-26")  # the pair holds π/2 to 2^-86
    assert trig.TWO_OVER_PI == 2.0 / math.pi


def test_within_one_ulp_of_the_c_library_on_every_latitude():
    """Against np.sin / np.cos (the C library's, correctly rounded on glibc; within 1 ulp on any libm
    NumPy uses, hence the 2-ulp bound): measured here 1 ulp at most, 93 % (sin) and 85 % (cos) equal. At
    the poles themselves cos L is ~6e-17 and its error absolute (below 1e-25, the split of π/2)."""
    edge = np.pi / 2 - 1e-9
    x = np.random.default_rng(0).uniform(-edge, edge, 400_000)
    x = np.concatenate([x, [0.0, 1e-300, -1e-12, np.pi / 4, -np.pi / 4, edge, -edge, 1.5, -1.5]])
    s, c = trig.sin_cos(x)
    assert ulps(s, np.sin(x)).max() <= 2.0
    assert ulps(c, np.cos(x)).max() <= 2.0
    assert np.mean(s == np.sin(x)) > 0.8 and np.mean(c == np.cos(x)) > 0.7
    poles = np.array([np.pi / 2, -np.pi / 2])
    s, c = trig.sin_cos(poles)
    assert np.array_equal(s, [1.0, -1.0]) and np.abs(c - np.cos(poles)).max() < 1e-25


def test_nan_beyond_three_quarters_pi_and_no_warning():
    x = np.array([2.4, -2.4, 3.0, 1e6, np.nan, np.inf])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s, c = trig.sin_cos(x)
    assert np.isnan(s).all() and np.isnan(c).all()
    s, c = trig.sin_cos(np.array([2.3, -2.3]))  # inside 3π/4: still the sine
    assert ulps(s, np.sin([2.3, -2.3])).max() <= 2.0 and ulps(c, np.cos([2.3, -2.3])).max() <= 2.0


def test_compiled_gives_the_same_bits():
    kernels = pytest.importorskip("nespm_cli.nav.kernels")
    if kernels.numba is None:
        pytest.skip("numba is not installed: the kernels run the NumPy reference")
    x = np.random.default_rng(1).uniform(-2.3, 2.3, 2000)
    s, c = trig.sin_cos(x)
    got = np.array([kernels.sin_cos_t(float(v)) for v in x])
    assert np.array_equal(got[:, 0], s) and np.array_equal(got[:, 1], c)


def test_extended_precision_input_to_float64_accuracy():
    """np.longdouble positions (tests that difference them): reduced in their own precision, float64's accuracy."""
    x = np.random.default_rng(2).uniform(-1.5, 1.5, 10_000).astype(np.longdouble)
    s, c = trig.sin_cos(x)
    assert s.dtype == np.longdouble
    assert float(np.abs(s - np.sin(x)).max()) < 4e-16 and float(np.abs(c - np.cos(x)).max()) < 4e-16
