"""A USBL position fix whose noise grows with the range to its beacon, as an nespm sensor plugin.

Written only against nespm's public sensor API (docs/sensors.md): ``nespm_cli.sensors`` (the
base classes and ``register``) and ``nespm_cli.sensors.fix`` (the position-fix measurement model,
reused: a USBL fix is a 3-D position fix with its own noise). Registered as ``usbl``.

Run it beside a DVL, in two worker processes or on Dask::

    nespm mc --sensor-plugin examples/usbl_sensor.py --state 15 --sensors dvl,usbl \\
        --sensor-option usbl.interval=5 --tracks 5 --runs 8 --jobs 2

The model (a common first-order USBL error budget):

* the transponder on the vehicle is fixed by a ship-side transceiver (the beacon) at
  ``beacon_lat``, ``beacon_lon`` [deg] on the surface (default: above each track's origin, the
  vehicle's position at t = 0, ``truth.track`` / ``ctx.track``); the fix is the transponder's position;
* its std per axis is ``std + range_ppm x 1e-6 x slant range`` [m] (defaults 0.5 m and
  1 % of the range = 10,000 ppm, typical of a compact USBL), drawn per fix from the truth's range
  and told to the filter with the range from the filter's own solution;
* everything else (interval, jitter, outage, dropout, lever arm) is the common sensor options'.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nespm_cli.sensors import Sensor, SensorOptions, register
from nespm_cli.sensors.fix import FixMeasurement, fix_values


@dataclass(frozen=True)
class UsblOptions(SensorOptions):
    """USBL options: the common ones (``std`` the range-independent part, default 0.5 m; a fix
    every 5 s) and the beacon's place and the range-proportional part."""

    std: float = 0.5
    interval: float | None = 5.0
    beacon_lat: float | None = None  # deg; None: the track origin's latitude
    beacon_lon: float | None = None  # deg; None: the track origin's longitude
    range_ppm: float = 10_000.0  # std growth, parts per million of the slant range


@register("usbl")
class Usbl(Sensor):
    """A 3-D position fix [lat, lon, alt] with a range-dependent std."""

    dim = 3
    labels = ("lat", "lon", "alt")
    observes = ("pos",)
    Options = UsblOptions

    def beacon(self, track) -> tuple[float, float]:
        """The beacon's ``(lat, lon)`` [rad] on a track (``track``: its TrackInfo; origin [lat, lon, h])."""
        o = self.opt
        lat = np.radians(o.beacon_lat) if o.beacon_lat is not None else track.origin[0]
        lon = np.radians(o.beacon_lon) if o.beacon_lon is not None else track.origin[1]
        return float(lat), float(lon)

    def slant_range(self, pos: np.ndarray, track) -> np.ndarray:
        """Range [m] (...,) from the beacon (on the surface) to positions ``pos`` (..., 3) [lat, lon, h]."""
        lat0, lon0 = self.beacon(track)
        R = 6_371_000.0
        dn = (pos[..., 0] - lat0) * R
        de = (pos[..., 1] - lon0) * R * np.cos(pos[..., 0])
        return np.sqrt(dn**2 + de**2 + pos[..., 2] ** 2)

    def stds(self, pos: np.ndarray, track, filter_side: bool) -> np.ndarray:
        """Per-axis std [m] (..., 3) at positions ``pos``."""
        base = self.r_std() if filter_side else self.noise_std()
        s = base + self.opt.range_ppm * 1e-6 * self.slant_range(pos, track)
        return np.repeat(s[..., None], 3, axis=-1)

    def true_values(self, truth) -> np.ndarray:
        return fix_values(truth.pos, truth.C_bn, self.opt.lever_arm, 3)

    def synthesize(self, truth, seed: int, track: int, runs: np.ndarray) -> np.ndarray:
        """Fixes (R, K, 3): the transponder's true position moved by N(0, std(range)²) per axis,
        each run from this sensor's own seed stream."""
        errors = np.stack([self.rng(seed, track, int(r)).standard_normal((len(truth.t), 3)) for r in runs])
        return fix_values(truth.pos, truth.C_bn, self.opt.lever_arm, 3, errors * self.stds(truth.pos, truth.track, False))

    def measurement(self, z, nav, ctx, layout):
        return FixMeasurement(z, self.opt.lever_arm, self.stds(nav.pos, ctx.track, True), layout)
