"""Oracle filters: ``NAME-oracle``, the filter ``NAME`` told the true noise of each realization.

The yardstick of an adaptive filter (docs/adapting.md). ``ekf-oracle`` is the ``ekf`` whose

* **Q(t)**: white-noise blocks (velocity: accelerometer, attitude: gyro) are the variances the
  realization's IMU noise was drawn with over each time-update span, i.e. the corruption's per-sample
  std times the schedule factor of every IMU step of the span (``--schedule dynamic``: a factor per
  segment and run), as the PSD ``σ² dt_imu`` of :func:`nespm_cli.filters.model.process_noise`: over a
  span of steps j, ``q = dt_imu Σ_j σ_j² dt_j`` (exact for the piecewise-constant schedule; a span
  that straddles a segment boundary gets the time-weighted mean variance). The bias random walks
  stay the filter's (the truth has none with ``--dynamic-bias run``; the base filter's are kept so
  that the oracle differs from it only in the white noise);
* **R(t)**: per measurement and run, the sensor's R scaled by ``(σ_true / σ_told)²`` with
  ``σ_true`` = :meth:`nespm_cli.sensors.source.Sensor.true_std` (its ``std`` times its
  ``noise_schedule`` factor) and ``σ_told`` the std the filter would use (``r_std`` times the
  filter's ``r_scale``); rows a sensor masks (a lost beam) are left as they are. Outliers are
  **not** in R: they are not Gaussian noise of a known variance (a contaminated Gaussian's variance
  would make the oracle pessimistic on the 95 % of good samples); a robust update treats them.
  A recorded sensor (or a recorded IMU's own noise) has no known truth: its R (Q) stays the filter's.

Everything else (propagation, update, options, robust update) is ``NAME``'s, so on a constant-noise
scenario with every sensor told its true std the oracle **is** ``NAME`` (the same Q and R: bit for
bit with a factor of 1 everywhere; tests/test_oracle.py).

How it gets the truth. The truth of a chunk is an :class:`OracleNoise` (built by
:func:`nespm_cli.experiments.realizations.oracle_noise` from the realization and the channels),
passed to ``run_filter`` as ``noise_std`` (the engine hands it to the filter's constructor; an
oracle does not ``needs_noise_std``, so no ProcessNet pass runs for it). The engine calls
``update(measurement, j_last)`` without naming the sensor: the oracle finds the measurement's channel
from its time (the split-grid sample ``j_last + 1``, the engine's own :class:`~.timeline.Timeline`),
its dimension and the runs where it exists, in channel order (the order the engine applies them).

Which filters have one: every registered filter with a covariance built on
:class:`~nespm_cli.filters.protocol.ErrorStateFilter` that does not adapt its own noise
(:func:`oracle_able`); an adaptive filter's oracle is its fixed counterpart's
(:func:`fixed_counterpart`: ``anekf``, ``iae-ekf``, ``sh-ekf``, ``vb-ekf``, ``aq-ekf`` → ``ekf-oracle``).
A plugin filter's oracle is valid when its ``propagate`` takes Q from ``process_noise`` and its
``update`` uses ``measurement.R``, as the built-ins do. Oracles have no RTS smoother.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.filters.adaptive import REFERENCE_ACC, REFERENCE_GYRO
from nespm_cli.filters.model import process_noise
from nespm_cli.filters.protocol import ErrorStateFilter
from nespm_cli.filters.timeline import Timeline
from nespm_cli.sensors.source import Channel

ORACLE_SUFFIX = "-oracle"
#: the built-in filters that adapt their noise without naming their fixed twin in ``adaptive_of``
ADAPTIVE_BASES = {"iae-ekf": "ekf", "sh-ekf": "ekf", "vb-ekf": "ekf", "aq-ekf": "ekf"}


@dataclass
class OracleNoise:
    """The true noise of one chunk of R runs on one track (what an oracle is told).

    Attributes:
        acc_std, gyro_std: (R, S) the per-sample white-noise std [m/s², rad/s] of each run in each
            schedule segment (S = 1 for ``constant``).
        segment: (M,) the segment of each IMU step (of the unsplit grid).
        dt: (M,) the IMU step durations [s]; epoch_index: (N,) the GT epochs' samples (as given to
            ``run_filter``, from which the engine's time line is rebuilt).
        channels: the sensors' channels, in the order given to ``run_filter``.
        sensor_std: per channel, (R, K) the std each measurement's noise was drawn with
            (:meth:`Sensor.true_std`), or None where unknown (a recorded sensor).
    """

    acc_std: np.ndarray
    gyro_std: np.ndarray
    segment: np.ndarray
    dt: np.ndarray
    epoch_index: np.ndarray
    channels: list
    sensor_std: list

    def __post_init__(self) -> None:
        R = self.acc_std.shape[0]
        if self.gyro_std.shape != self.acc_std.shape or len(self.segment) != len(self.dt):
            raise NespmError("OracleNoise: acc_std/gyro_std must be (R, S) alike and segment (M,) as dt")
        if len(self.sensor_std) != len(self.channels):
            raise NespmError("OracleNoise: one sensor_std entry per channel")
        for ch, s in zip(self.channels, self.sensor_std):
            if s is not None and np.shape(s) != (R, len(ch.t)):
                raise NespmError(f"OracleNoise: {ch.sensor.name}'s true std has shape {np.shape(s)}, "
                                 f"expected ({R}, {len(ch.t)})")

    def interval_std(self) -> tuple[np.ndarray, np.ndarray]:
        """``(std_a, std_g)`` each (R, N-1): the RMS true std over each GT interval (time-weighted)."""
        e = np.asarray(self.epoch_index, dtype=np.int64)
        out = []
        for std in (self.acc_std, self.gyro_std):
            var = np.square(std)[:, self.segment] * self.dt  # (R, M)
            sums = np.add.reduceat(var[:, e[0]:e[-1]], e[:-1] - e[0], axis=1)
            span = np.add.reduceat(self.dt[e[0]:e[-1]], e[:-1] - e[0])
            out.append(np.sqrt(sums / span))
        return out[0], out[1]


def span_variance(std: np.ndarray, seg: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """(R,) the time-weighted mean variance over a span: ``Σ_j std[:, seg_j]² dt_j / Σ_j dt_j`` with
    ``std`` (R, S), ``seg`` (L,) the span's steps' segments (non-decreasing), ``dt`` (L,) [s]; a span
    inside one segment gives that segment's variance exactly (``std²``, no summation round-off)."""
    s0, s1 = int(seg[0]), int(seg[-1])
    if s0 == s1:
        return np.square(std[:, s0])
    w = np.bincount(seg - s0, weights=dt, minlength=s1 - s0 + 1)
    return (np.square(std[:, s0:s1 + 1]) @ w) / float(np.sum(dt))


class Oracle(ErrorStateFilter):
    """Mixin (before the base filter in the MRO) that tells a filter the true Q and R of its
    realizations (module docstring). ``oracle_of``: the base filter's name."""

    oracle_of: str = ""
    smoothable = False

    def __init__(self, cfg, nav0, imu, noise_std=None):
        truth = noise_std
        if not isinstance(truth, OracleNoise):
            raise NespmError(f"filter {self.name} is told the true noise of each realization: run it through nespm "
                             "mc or nespm run (run_filter needs noise_std=nespm_cli.experiments.realizations."
                             "oracle_noise(...))")
        super().__init__(cfg, nav0, imu, None)
        if truth.acc_std.shape[0] != self.R:
            raise NespmError(f"filter {self.name}: the true noise holds {truth.acc_std.shape[0]} runs, the batch {self.R}")
        line = Timeline(truth.dt, truth.epoch_index, truth.channels)
        if len(line.dt) != len(self.dt):
            raise NespmError(f"filter {self.name}: the true noise's time line ({len(line.dt)} steps) is not the "
                             f"filter's ({len(self.dt)}): give the channels passed to run_filter")
        base = np.arange(len(line.dt)) if line.base is None else line.base
        self.truth = truth
        self.step_segment = np.asarray(truth.segment, dtype=np.int64)[base]  # (M',) the segment of each split step
        self.at: dict[int, list] = {}  # split-grid sample -> [(channel, measurement)] in channel order
        for c, s in enumerate(line.samples):
            for i, b in enumerate(np.asarray(s).tolist()):
                if b > 0:
                    self.at.setdefault(b, []).append((c, i))
        self.span_steps = (0, 0)
        self.applied: tuple = (-1, -1)  # (sample, channel) of the last measurement told its R

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:
        self.span_steps = (j0, j1)
        super().propagate(j0, j1, k)

    def process_noise(self, span: float, k: int) -> np.ndarray:
        """(R, n, n) the filter's Q with its velocity and attitude blocks the true white noise over the
        steps of the current span (:func:`span_variance`), as the PSD ``σ² dt_imu`` times the span."""
        j0, j1 = self.span_steps
        Q = np.array(np.broadcast_to(process_noise(self.cfg, self.dt_imu, span), (self.R,) + (self.layout.n,) * 2))
        seg, dt = self.step_segment[j0:j1], self.dt[j0:j1]
        if len(seg) == 0:
            return Q
        idx = np.arange(3)
        for block, std in (("vel", self.truth.acc_std), ("att", self.truth.gyro_std)):
            if self.layout.has(block):
                i = self.layout.offset(block) + idx
                Q[:, i, i] = (span_variance(std, seg, dt) * self.dt_imu * span)[:, None]
        return Q

    def channel_of(self, measurement, j_last: int) -> tuple[int, int] | None:
        """``(channel, index)`` of ``measurement`` at split-grid sample ``j_last + 1`` (None: none found): those
        with a measurement there that exists in some run and has its dimension, in channel order after
        the one told last at this sample (the engine applies them in that order)."""
        b = int(j_last) + 1
        m = int(np.shape(measurement.z)[-1])
        last = self.applied[1] if self.applied[0] == b else -1
        for c, i in self.at.get(b, []):
            ch: Channel = self.truth.channels[c]
            if c > last and ch.z.shape[-1] == m and bool(np.asarray(ch.ok[:, i]).any()):
                self.applied = (b, c)
                return c, i
        return None

    def true_r(self, measurement, j_last: int) -> None:
        """Set ``measurement.R`` (R, m, m) to the true noise of its sensor at this sample, where known."""
        found = self.channel_of(measurement, j_last)
        if found is None or self.truth.sensor_std[found[0]] is None:
            return
        c, i = found
        std, ch = self.truth.sensor_std[c], self.truth.channels[c]
        told = ch.sensor.r_std() * self.cfg.r_factor(ch.sensor.name)
        s = np.asarray(std[:, i], dtype=float) / told  # (R,)
        if np.all(s == 1.0):
            return
        H = measurement.H(self.nav)
        d = np.where(np.any(H != 0.0, axis=-1), s[:, None], 1.0)  # (R, m): a masked row keeps its R
        Rm = np.broadcast_to(np.asarray(measurement.R, dtype=float), (self.R,) + (d.shape[-1],) * 2)
        measurement.R = d[:, :, None] * Rm * d[:, None, :]

    def update(self, measurement, j_last: int):
        self.true_r(measurement, j_last)
        return super().update(measurement, j_last)

    @property
    def noise_std(self):
        """``(std_a, std_g)`` each (R, N-1, 3): the true std of each GT interval over the filter's nominal,
        times the reference std, so ``mc``'s ``q_factor_acc`` / ``q_factor_gyro`` record the true factor."""
        a, g = self.truth.interval_std()
        return (np.repeat((a / self.cfg.acc_noise * REFERENCE_ACC)[..., None], 3, axis=-1),
                np.repeat((g / self.cfg.gyro_noise * REFERENCE_GYRO)[..., None], 3, axis=-1))


def oracle_able(cls: type, name: str = "") -> bool:
    """Whether filter class ``cls`` (registered as ``name``) has an oracle: a covariance, built on
    :class:`ErrorStateFilter`, not adapting its own noise, not an oracle itself."""
    return (isinstance(cls, type) and issubclass(cls, ErrorStateFilter) and bool(cls.has_covariance)
            and not cls.needs_noise_std and not getattr(cls, "adaptive_of", None) and name not in ADAPTIVE_BASES
            and not issubclass(cls, Oracle))


def oracle_class(base: type, base_name: str, builtin: bool) -> type:
    """The class of ``BASE-oracle``: :class:`Oracle` before ``base`` (its module the base's for a
    plugin, so its code is the plugin's; this module's for a built-in)."""
    return type(f"{base.__name__}Oracle", (Oracle, base),
                {"oracle_of": base_name, "name": base_name + ORACLE_SUFFIX,
                 "__module__": __name__ if builtin else base.__module__,
                 "__doc__": f"``{base_name}`` told the true Q(t) and R(t) of each realization (nespm_cli.filters.oracle)."})


def is_oracle(cls_or_name) -> bool:
    """Whether a filter class (or a name) is an oracle."""
    if isinstance(cls_or_name, str):
        return cls_or_name.endswith(ORACLE_SUFFIX)
    return isinstance(cls_or_name, type) and issubclass(cls_or_name, Oracle)


def fixed_counterpart(name: str, cls: type) -> str | None:
    """The fixed filter an adaptive filter ``name`` (class ``cls``) adapts: its ``adaptive_of``, else
    :data:`ADAPTIVE_BASES`; None for a filter that does not adapt its noise (or an oracle)."""
    if is_oracle(cls):
        return None
    return getattr(cls, "adaptive_of", None) or ADAPTIVE_BASES.get(name)


__all__ = ["ADAPTIVE_BASES", "ORACLE_SUFFIX", "Oracle", "OracleNoise", "fixed_counterpart", "is_oracle", "oracle_able",
           "oracle_class", "span_variance"]
