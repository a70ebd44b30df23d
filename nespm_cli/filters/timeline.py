"""The time line of a filter run: GT epochs and sensor times merged on the IMU step grid.

:class:`Timeline` takes the IMU step durations, the GT epochs' samples and the sensors' channels
(:class:`nespm_cli.sensors.source.Channel`), splits every IMU step that a measurement falls inside
(both parts keep the step's reading, as :func:`nespm_cli.nav.synthesis.recorded_grid` splits a
recorded IMU at the GT epochs), and lists the spans between consecutive event times with what
happens at their end. Without an off-grid measurement the grid is the IMU's own (the arrays pass
through unchanged, so the papers' runs keep their bits).
"""
from __future__ import annotations

from typing import Iterator

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.sensors.dvl import Dvl, DvlOptions
from nespm_cli.sensors.source import Channel

FRAC_TOL = 1e-9  # a measurement closer than this fraction of a step to a sample is at the sample


class Timeline:
    """Merged event times of one run of the engine.

    Attributes: ``dt`` (M',) the (split) step durations [s]; ``base`` (M',) the IMU step each
    split step reads (None: no split); ``epochs`` (N,) the GT epochs' samples on the split grid;
    ``samples`` one (K,) array per channel, the sample of each measurement on the split grid.
    """

    def __init__(self, dt: np.ndarray, epoch_index: np.ndarray, channels: list[Channel]):
        dt = np.asarray(dt, dtype=float)
        M = len(dt)
        cuts = []  # (step, fraction) of every off-grid measurement
        for ch in channels:
            if len(ch.index) and (ch.index.min() < 0 or ch.index.max() > M):
                raise NespmError(f"{ch.sensor.name}: a measurement lies outside the IMU record")
            off = ch.frac > FRAC_TOL
            cuts += list(zip(ch.index[off].tolist(), ch.frac[off].tolist()))
        cuts = sorted(set(cuts))
        if not cuts:
            self.dt, self.base = dt, None
            self.epochs = np.asarray(epoch_index, dtype=np.int64)
            self.samples = [np.where(ch.frac > FRAC_TOL, -1, ch.index) for ch in channels]
        else:
            self._split(dt, epoch_index, channels, cuts)
        self.channels = channels

    def _split(self, dt, epoch_index, channels, cuts) -> None:
        step = np.array([c[0] for c in cuts])
        frac = np.array([c[1] for c in cuts])
        # new index of original sample j: j plus the cuts in steps before j
        shift = np.searchsorted(step, np.arange(len(dt) + 1), side="left")
        new_of = np.arange(len(dt) + 1) + shift
        base = np.repeat(np.arange(len(dt)), np.bincount(step, minlength=len(dt)) + 1)
        # the fractions bounding each split step: 0, the cuts of its step, 1
        rank = np.arange(len(cuts)) - np.searchsorted(step, step, side="left")  # of each cut in its step
        before = new_of[step] + rank  # the split step that ends at each cut
        lo, hi = np.zeros(len(base)), np.ones(len(base))
        hi[before], lo[before + 1] = frac, frac
        self.dt = dt[base] * (hi - lo)
        self.base = base
        self.epochs = new_of[np.asarray(epoch_index, dtype=np.int64)]
        key = step + frac  # increasing with the sorted cuts (0 < frac < 1)
        self.samples = [np.where(ch.frac > FRAC_TOL,
                                 before[np.clip(np.searchsorted(key, ch.index + ch.frac), 0, len(key) - 1)] + 1,
                                 new_of[ch.index]).astype(np.int64)
                        for ch in channels]

    def expand(self, a: np.ndarray) -> np.ndarray:
        """An IMU array (R, M, ...) on the split grid (R, M', ...) (itself without a split)."""
        return a if self.base is None else a[:, self.base]

    def spans(self) -> Iterator[tuple[int, int, int, int | None, list]]:
        """``(a, b, k, epoch, todo)`` per span of samples ``[a, b)`` between consecutive events:
        ``k`` the GT interval holding it, ``epoch`` the GT epoch at ``b`` (None if none), ``todo``
        the measurements at ``b`` as ``(channel, i)`` in channel order."""
        at: dict[int, list] = {}
        for c, s in enumerate(self.samples):
            for i, b in enumerate(s.tolist()):
                if b > 0:
                    at.setdefault(b, []).append((c, i))
        ep = self.epochs
        events = np.union1d(ep[1:], np.array(sorted(b for b in at if b <= ep[-1]), dtype=np.int64))
        epoch_at = {int(b): e for e, b in enumerate(ep.tolist())}
        a = int(ep[0])
        for b in events.tolist():
            k = int(np.searchsorted(ep, a, side="right")) - 1
            yield a, b, k, epoch_at.get(b), at.get(b, [])
            a = b


def dvl_channel(dvl: np.ndarray, dvl_mask: np.ndarray | None, cfg, dt: np.ndarray, epoch_index: np.ndarray) -> Channel:
    """The papers' DVL at the GT epochs as a channel: values ``dvl`` (R, N, 3), applied where
    ``dvl_mask`` (N,) (None: every epoch but the first), with ``cfg.dvl_std`` and ``cfg.lever_arm``."""
    e = np.asarray(epoch_index, dtype=np.int64)
    R = dvl.shape[0]
    mask = np.ones(len(e), dtype=bool) if dvl_mask is None else np.asarray(dvl_mask, dtype=bool).copy()
    mask[0] = False
    t = np.concatenate([[0.0], np.cumsum(dt)])[e]
    sensor = Dvl(DvlOptions(r_std=float(cfg.dvl_std), lever_arm=tuple(float(x) for x in cfg.lever_arm)))
    sensor.name = "dvl"
    return Channel(sensor, e, t, dvl, np.broadcast_to(mask, (R, len(e))))


__all__ = ["FRAC_TOL", "Timeline", "dvl_channel"]
