"""Closed-loop batched REMUS 100 helix runs (gp-ukf.md section 6) and A-KIT track export.

Timing (three rates, all fixed):

* **integration** ``integration_hz`` (100 Hz): classical RK4 of eqs 1-2, commands held;
* **control** ``control_hz`` (10 Hz): the sensors are sampled and the LOS/PIDs run on the
  corrupted measurements; the command is held until the next control instant;
* **output** ``output_hz`` (5 Hz, the paper's capture rate): the samples stored in
  :class:`SimResult`; the 100 Hz truth is kept too (``x_fine``) for the 100 Hz IMU.

Each output sample k at ``t_k`` holds the true state, the measurement taken at ``t_k`` and the
command computed from it (applied on ``[t_k, t_k + 1/control_hz)``).

Randomness: run ``r`` draws its sensor noise from
``default_rng(SeedSequence(seed, spawn_key=(r, SENSOR_STREAM)))``, so a run depends only on
``(seed, r)`` -- not on the batch it is simulated in. The only loop over runs is this
generator set-up; the dynamics, sensors and controllers are vectorized over runs.
"""
from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nespm_cli.nav.earth import radii
from nespm_cli.nav.rotations import euler_to_dcm
from nespm_cli.nav.strapdown import na_cycle_inverse
from nespm_cli.nav.synthesis import integrate_position
from nespm_cli.data.atomic import write_atomic
from nespm_cli.data.tracks import Track, write_akit
from nespm_cli.errors import NespmError
from nespm_cli.vehicles.guidance import GuidanceGains, GuidanceState, Helix, control_step
from nespm_cli.vehicles.remus100 import IPHI, IPSI, ITHETA, IU, IW, IX, IZ, Remus100, Remus100Params
from nespm_cli.nav.rotations import wrap_angle
from nespm_cli.vehicles.sensors import SensorSuite, draw_noise, measure

SENSOR_STREAM = 0  # spawn_key stream of the sensor noise
#: default geodetic origin of the local NED frame (the helix axis at the surface): off Haifa,
#: the same area as the Snapir tracks and nespm_cli.data.embedded
LAT0 = float(np.radians(32.84))
LON0 = float(np.radians(34.93))
IMU_HZ = 100  # rate of the written IMU file [Hz]
GT_HZ = 1  # rate of the written GT / DVL files [Hz]


@dataclass(frozen=True)
class InitialCondition:
    """Start of every run, relative to the helix start point.

    Defaults follow the GP-UKF authors' public simulator (vehicle 3 m off the path start,
    1 m above it, heading 45 deg off the path course, surge 0.5 m/s: "accelerated from an
    initial velocity of 0.5 m/s to 1.4 m/s").

    Attributes:
        u: initial surge [m/s] (v = w = p = q = r = 0, level: theta = phi = 0).
        offset_ned: (north, east, down) offset from P(phase_start) [m].
        heading_offset: psi0 - chi_p(start) [rad], multiplied by the helix direction.
    """

    u: float = 0.5
    offset_ned: tuple[float, float, float] = (0.0, 3.0, -1.0)
    heading_offset: float = float(np.pi / 4)

    def state(self, helix: Helix) -> np.ndarray:
        """The initial 12-state (paper order)."""
        x = np.zeros(12)
        x[IU] = self.u
        x[IX:IZ + 1] = helix.point(helix.phase_start) + np.asarray(self.offset_ned, dtype=float)
        x[IPSI] = wrap_angle(helix.course(helix.phase_start) + helix.direction * self.heading_offset)
        return x


@dataclass(frozen=True)
class SimResult:
    """Output of :func:`simulate_runs` (R runs, N output samples, M integration steps).

    Attributes:
        t: (N,) output times [s] (0, 1/output_hz, ...).
        x: (R, N, 12) true state ``[u, v, w, p, q, r, X, Y, Z, theta, psi, phi]`` (paper order;
            m/s, rad/s, m (local NED about the helix axis at the surface), rad; psi wrapped to
            (-pi, pi]).
        u: (R, N, 3) applied (saturated) commands ``[rpm, delta_s, delta_r]`` [rev/min, rad, rad].
        z: (R, N, 10) measurements ``[u, v, w, p, q, r, Z, theta, psi, phi]`` (noisy, 12-bit).
        path_error: (R, N, 3) true position relative to the guidance point P(t) in the path
            frame ``[along, cross (right +), vertical (below +)]`` [m].
        path_point: (R, N, 3) P(t) [north, east, depth] [m].
        nav: (R, N, 3) the controller's dead-reckoned position [m].
        t_fine: (M+1,) integration times [s]; x_fine: (R, M+1, 12) true state at every
            integration step (psi wrapped), or None if ``keep_fine=False``.
        runs: (R,) run indices (noise streams); seed: master seed.
        integration_hz, control_hz, output_hz: the three rates [Hz].
        helix, params: the path and vehicle used.
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    z: np.ndarray
    path_error: np.ndarray
    path_point: np.ndarray
    nav: np.ndarray
    t_fine: np.ndarray
    x_fine: np.ndarray | None
    runs: np.ndarray
    seed: int
    integration_hz: float
    control_hz: float
    output_hz: float
    helix: Helix = field(default_factory=Helix)
    params: Remus100Params = field(default_factory=Remus100Params)

    @property
    def cross_track(self) -> np.ndarray:
        """(R, N) distance from P(t) across the path: ``hypot(cross, vertical)`` [m]."""
        return np.hypot(self.path_error[..., 1], self.path_error[..., 2])


def _ratio(a: float, b: float, what: str) -> int:
    k = int(round(a / b))
    if k < 1 or abs(k * b - a) > 1e-9 * a:
        raise ValueError(f"{what}: {a:g} Hz is not a whole multiple of {b:g} Hz")
    return k


def simulate_runs(
    n_runs: int,
    duration_s: float = 800.0,
    seed: int = 0,
    *,
    runs: Sequence[int] | None = None,
    params: Remus100Params | None = None,
    sensors: SensorSuite | None = None,
    helix: Helix | None = None,
    gains: GuidanceGains | None = None,
    initial: InitialCondition | None = None,
    integration_hz: float = 100.0,
    control_hz: float = 10.0,
    output_hz: float = 5.0,
    keep_fine: bool = True,
) -> SimResult:
    """Simulate ``n_runs`` closed-loop helix runs of ``duration_s`` seconds, batched.

    Args:
        n_runs: number of runs (indices 0..n_runs-1); ignored when ``runs`` is given.
        duration_s: length [s]; must be a whole number of control periods.
        seed: master seed; run r's noise comes from ``SeedSequence(seed, spawn_key=(r, 0))``.
        runs: explicit run indices to simulate (e.g. ``[3]`` reproduces run 3 of a batch).
        params, sensors, helix, gains, initial: model, sensor suite, path, controller gains and
            start (defaults: the documented ones).
        integration_hz, control_hz, output_hz: rates; each must divide the previous one.
        keep_fine: keep the integration-rate truth (needed by :func:`to_track`); R x M x 12 floats.

    Returns:
        :class:`SimResult`.
    """
    params = Remus100Params() if params is None else params
    sensors = SensorSuite() if sensors is None else sensors
    helix = Helix() if helix is None else helix
    gains = GuidanceGains() if gains is None else gains
    initial = InitialCondition() if initial is None else initial
    run_ids = np.arange(n_runs) if runs is None else np.asarray(runs, dtype=int).reshape(-1)
    R = len(run_ids)
    if R == 0:
        raise ValueError("simulate_runs: no runs")
    sub = _ratio(integration_hz, control_hz, "integration_hz / control_hz")
    per_out = _ratio(control_hz, output_hz, "control_hz / output_hz")
    n_ctrl = int(round(duration_s * control_hz))
    if n_ctrl < 1 or abs(n_ctrl / control_hz - duration_s) > 1e-9 * max(1.0, duration_s):
        raise ValueError(f"duration_s={duration_s:g} is not a whole number of control periods")
    h = 1.0 / integration_hz
    dt_ctrl = 1.0 / control_hz
    n_out = n_ctrl // per_out + 1
    M = n_ctrl * sub

    model = Remus100(params)
    rngs = [np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(int(r), SENSOR_STREAM))) for r in run_ids]
    xi = draw_noise(rngs, n_ctrl + 1)  # (R, n_ctrl + 1, 10)

    x = np.tile(initial.state(helix), (R, 1))
    gstate = GuidanceState.start(helix, x[:, IX:IZ + 1])

    out_x = np.empty((R, n_out, 12))
    out_u = np.empty((R, n_out, 3))
    out_z = np.empty((R, n_out, 10))
    out_e = np.empty((R, n_out, 3))
    out_p = np.empty((R, n_out, 3))
    out_nav = np.empty((R, n_out, 3))
    x_fine = np.empty((R, M + 1, 12)) if keep_fine else None

    def wrapped(s: np.ndarray) -> np.ndarray:
        s = s.copy()
        s[..., IPSI] = wrap_angle(s[..., IPSI])
        return s

    for k in range(n_ctrl + 1):
        z = measure(x, xi[:, k], sensors)
        varpi_k = gstate.varpi.copy()  # P(t_k): the point this cycle's command chases
        cmd = control_step(gstate, z, dt_ctrl, helix, gains, params)
        if k % per_out == 0:
            j = k // per_out
            out_x[:, j] = wrapped(x)
            out_u[:, j] = cmd
            out_z[:, j] = z
            out_p[:, j] = helix.point(varpi_k)
            out_e[:, j] = helix.errors(x[:, IX:IZ + 1], varpi_k)
            out_nav[:, j] = gstate.nav
        if keep_fine:
            x_fine[:, k * sub] = wrapped(x)
        if k == n_ctrl:
            break
        for i in range(sub):
            x = model.rk4_step(x, cmd, h)
            if keep_fine and i < sub - 1:
                x_fine[:, k * sub + i + 1] = wrapped(x)

    return SimResult(
        t=np.arange(n_out) / output_hz,
        x=out_x,
        u=out_u,
        z=out_z,
        path_error=out_e,
        path_point=out_p,
        nav=out_nav,
        t_fine=np.arange(M + 1) / integration_hz,
        x_fine=x_fine,
        runs=run_ids,
        seed=int(seed),
        integration_hz=float(integration_hz),
        control_hz=float(control_hz),
        output_hz=float(output_hz),
        helix=helix,
        params=params,
    )


# ----------------------------------------------------------------------------- A-KIT export


def geodetic_origin_offset(ned: np.ndarray, lat0: float, lon0: float) -> np.ndarray:
    """``[lat, lon, h]`` (3,) of a local NED point ``ned`` (3,) [m] about the surface origin
    ``(lat0, lon0, 0)`` (the inverse of :func:`nespm_cli.nav.earth.ned_offset`)."""
    R_N, R_E = radii(np.asarray(lat0, dtype=float))
    n, e, d = (float(c) for c in ned)
    return np.array([lat0 + n / R_N, lon0 + e / (R_E * np.cos(lat0)), -d])


def to_track(
    result: SimResult,
    run: int,
    number: int,
    lat0: float = LAT0,
    lon0: float = LON0,
    dvl: str = "measured",
) -> Track:
    """The A-KIT track of batch entry ``run`` (0..R-1) of ``result``, numbered ``number``.

    * GT and DVL at 1 Hz on ``t = 0, 1, ..., floor(duration)`` s;
    * IMU at 100 Hz: each GT interval split in 100 steps (as :func:`nespm_cli.nav.synthesis.synthesize`
      builds its grid), row ``i >= 1`` at ``t_i`` holds the specific force and angular rate of
      step ``i - 1`` (from sample i-1 to i), which is how :func:`synthesis.from_recorded`
      reads it; row 0 repeats step 0. They are the exact inverse strapdown
      (:func:`strapdown.na_cycle_inverse`) of the simulated 100 Hz truth, so ``na_cycle`` from
      the first GT epoch reproduces the truth to round-off;
    * position: the start is the simulated NED start about the origin ``(lat0, lon0, 0 m)``
      (:func:`geodetic_origin_offset`); from there latitude / longitude / height are
      integrated from the NED velocity ``C_bn [u, v, w]`` by eqs 28-30 (trapezoid, WGS-84
      radii, :func:`synthesis.integrate_position`), so position is consistent with the IMU;
      it differs from the flat-earth simulator position by millimetres (docs/remus100.md);
    * attitude ``[roll, pitch, yaw] = [phi, theta, psi]`` (yaw wrapped), velocity NED;
    * DVL: ``"measured"`` (the noisy 12-bit DVL of the run at the GT epochs) or ``"true"``
      (body velocity ``[u, v, w]``). The DVL is at the body origin (no lever arm).

    Requires ``result.x_fine`` (``keep_fine=True``), an integration rate that is a multiple of
    100 Hz, an integer output rate and at least 3 s of simulation.
    """
    if result.x_fine is None:
        raise ValueError("to_track needs the integration-rate truth: simulate with keep_fine=True")
    if dvl not in ("measured", "true"):
        raise ValueError(f"dvl must be 'measured' or 'true', got {dvl!r}")
    step = _ratio(result.integration_hz, IMU_HZ, "integration_hz / IMU rate")
    out_per_gt = _ratio(result.output_hz, GT_HZ, "output_hz / GT rate")
    duration = float(result.t_fine[-1])
    n_gt = int(np.floor(duration * GT_HZ + 1e-9)) + 1
    if n_gt < 4:
        raise ValueError(f"to_track needs at least 3 s of simulation, got {duration:g} s")
    t_gt = np.arange(n_gt, dtype=float) / GT_HZ
    frac = np.arange(IMU_HZ // GT_HZ) / (IMU_HZ // GT_HZ)
    t_imu = np.concatenate([(t_gt[:-1, None] + np.diff(t_gt)[:, None] * frac).ravel(), t_gt[-1:]])
    epoch = np.arange(n_gt) * (IMU_HZ // GT_HZ)  # GT epoch k is IMU sample epoch[k]
    xs = result.x_fine[run, : step * (len(t_imu) - 1) + 1 : step]  # (M + 1, 12) on the IMU grid

    euler = np.stack([xs[:, IPHI], xs[:, ITHETA], wrap_angle(xs[:, IPSI])], axis=-1)
    C_bn = euler_to_dcm(euler)
    v_n = (C_bn @ xs[:, IU:IW + 1, None])[..., 0]
    dt = np.diff(t_imu)
    pos0 = geodetic_origin_offset(xs[0, IX:IZ + 1], lat0, lon0)
    pos = integrate_position(pos0, v_n, dt)
    f_b, w_ib_b = na_cycle_inverse(pos[:-1], v_n[:-1], C_bn[:-1], pos[1:], v_n[1:], C_bn[1:], dt)
    imu = np.column_stack([t_imu, np.vstack([f_b[:1], f_b]), np.vstack([w_ib_b[:1], w_ib_b])])

    if dvl == "measured":
        dvl_b = result.z[run, np.arange(n_gt) * out_per_gt, 0:3]
    else:
        dvl_b = xs[epoch, IU:IW + 1]
    return Track(
        number=int(number),
        t=t_gt,
        pos=pos[epoch],
        v_n=v_n[epoch],
        euler=euler[epoch],
        dvl=dvl_b,
        imu=imu,
        source=f"remus100-sim seed {result.seed} run {int(result.runs[run])}",
    )


#: the marker :func:`write_tracks` leaves in a folder it wrote: the options its tracks came from
MARKER = ".nespm-simulate.json"
_TRACK_ENTRY = re.compile(r"Trajectory(\d*).*")


def simulate_record(result: SimResult, first_number: int = 1, lat0: float = LAT0, lon0: float = LON0,
                    dvl: str = "measured") -> dict:
    """The content of :data:`MARKER` for writing ``result`` with these options (JSON-ready).

    ``options`` are what determine the written files: ``runs`` (count), ``run_indices`` (noise
    streams), ``duration_s`` [s], ``seed``, ``first_number``, ``dvl``, ``lat0`` / ``lon0`` [rad], the
    three rates [Hz] and ``model`` (SHA-256 of the helix and vehicle parameters); ``tracks`` and
    ``folders`` name what is written.
    """
    numbers = [first_number + i for i in range(result.x.shape[0])]
    model = hashlib.sha256(repr((result.helix, result.params)).encode()).hexdigest()[:16]
    options = {"runs": len(numbers), "run_indices": [int(r) for r in result.runs],
               "duration_s": float(result.t_fine[-1]), "seed": int(result.seed), "first_number": int(first_number),
               "dvl": dvl, "lat0": float(lat0), "lon0": float(lon0), "integration_hz": result.integration_hz,
               "control_hz": result.control_hz, "output_hz": result.output_hz, "model": model}
    return {"kind": "nespm-simulate", "version": 1, "options": options, "tracks": numbers,
            "folders": [f"Trajectory{n}" for n in numbers]}


def check_simulate_folder(folder: str | Path, record: dict) -> None:
    """Refuse (NespmError, one line) to write ``record`` (:func:`simulate_record`) into ``folder`` when
    it holds a ``Trajectory*`` entry that an earlier :func:`write_tracks` with the same options did
    not write (its :data:`MARKER` lists it and records the same ``options``): e.g. real tracks. A
    missing folder or one without ``Trajectory*`` entries is fine. Writes nothing."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise NespmError(f"{folder}: exists and is not a folder; nothing was written")
    if not folder.exists():
        return
    try:
        entries = [p.name for p in folder.iterdir() if _TRACK_ENTRY.fullmatch(p.name)]
    except OSError as exc:
        raise NespmError(f"{folder}: cannot list the folder ({exc.strerror or exc}); nothing was written") from None
    entries.sort(key=_entry_order)
    if not entries:
        return
    marker, why = _read_marker(folder / MARKER)
    if marker is not None:
        old = marker.get("options") if isinstance(marker.get("options"), dict) else {}
        diff = [k for k in record["options"] if old.get(k) != record["options"][k]]
        ours = set(marker.get("folders") or []) if not diff else set()
        why = (f"{MARKER} records {diff[0]} {old.get(diff[0])!r}, not {record['options'][diff[0]]!r}" if diff
               else f"{MARKER} does not list it")
    else:
        ours = set()
    for name in entries:
        if name not in ours:
            raise NespmError(f"{folder}: holds {name}, which nespm simulate did not write with these options "
                             f"({why}); nothing was written: choose a new or empty folder")


def _entry_order(name: str) -> tuple[int, str]:
    """Sort key of a ``Trajectory*`` name: by track number (none first), then by name."""
    digits = _TRACK_ENTRY.fullmatch(name).group(1)
    return (int(digits) if digits else -1, name)


def _read_marker(path: Path) -> tuple[dict | None, str]:
    """``(marker, "")`` or ``(None, why not)``: the :data:`MARKER` of a folder."""
    if not path.is_file():
        return None, f"no {MARKER} in the folder"
    try:
        marker = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):
        return None, f"{MARKER} is unreadable"
    if not (isinstance(marker, dict) and marker.get("kind") == "nespm-simulate"):
        return None, f"{MARKER} is not a nespm simulate marker"
    return marker, ""


def write_tracks(
    result: SimResult,
    folder: str | Path,
    first_number: int = 1,
    lat0: float = LAT0,
    lon0: float = LON0,
    dvl: str = "measured",
) -> list[Path]:
    """Write every run of ``result`` as ``folder/TrajectoryN/{GT,DVL,IMU}_trajectoryN.csv``.

    Run i (batch position) becomes track ``first_number + i`` (:func:`to_track`,
    :func:`nespm_cli.data.tracks.write_akit`). Returns the written ``TrajectoryN`` folders.

    First, before anything is written, :func:`check_simulate_folder` refuses a folder holding
    ``Trajectory*`` entries that this function did not write with the same options (e.g. real
    data: never overwritten). Then the marker :data:`MARKER` (:func:`simulate_record`: seed,
    duration, runs, first number, DVL mode, origin, rates, track folders) is written, then the
    tracks; the same call again rewrites the same files.
    """
    folder = Path(folder)
    record = simulate_record(result, first_number, lat0, lon0, dvl)
    check_simulate_folder(folder, record)
    folder.mkdir(parents=True, exist_ok=True)
    write_atomic(folder / MARKER, lambda tmp: tmp.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8"))
    return [
        write_akit(to_track(result, i, first_number + i, lat0, lon0, dvl), folder)
        for i in range(result.x.shape[0])
    ]
