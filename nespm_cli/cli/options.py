"""The option tables of the ``nespm`` commands and the decorator that gives a command a table's
options: one tuple ``(name, type, default, flag, help)`` per option, defaults from the config
dataclasses (:func:`default`), never written twice."""
from __future__ import annotations

import functools
import inspect
from typing import List, Optional, Tuple

import typer

# DATA_DIR is given from here too (check, train, nespm_cli.cli.DATA_DIR); it lives in the light data_options for tracks
from nespm_cli.cli.data_options import ACCEPT_RESIDUAL_FLAG, ACCEPT_RESIDUAL_HELP, DATA_DIR, DATA_DIR_HELP
from nespm_cli.data.corruption import CorruptionConfig
from nespm_cli.experiments.metrics import DivergenceRule
from nespm_cli.experiments.spec import Spec
from nespm_cli.filters import FILTERS, FilterConfig  # the built-in names: registered on this import, no extra cost
from nespm_cli.filters.registry import get_filter

#: the built-in filters with an RTS smoother (``--smooth``), from the registry: never stale
SMOOTHABLE = tuple(f for f in FILTERS if getattr(get_filter(f), "smoothable", False))


def default(cls, name: str):
    """The default of field ``name`` of dataclass ``cls``: the one place every option default lives."""
    import dataclasses

    f = next(f for f in dataclasses.fields(cls) if f.name == name)
    return f.default if f.default is not dataclasses.MISSING else f.default_factory()


CORRUPTION = [  # (name, type, default, flag, help): the realizations (mc, sweep, run, corrupt)
    ("schedule", str, default(CorruptionConfig, "schedule"), "--schedule", "IMU error schedule: constant (UKF-NESPM paper) or dynamic (ANUKF paper: noise and bias x U[1,6] per segment)."),
    ("segment_length", float, default(CorruptionConfig, "segment_s"), "--segment-length", "Dynamic schedule segment [s]."),
    ("dynamic_bias", str, default(CorruptionConfig, "dynamic_bias"), "--dynamic-bias", "Dynamic schedule biases: run (x the run's first-segment factor, held) or segment (x every segment's factor: 20 s bias steps)."),
    ("seed", int, default(Spec, "seed"), "--seed", "Master seed; run r of track N draws from SeedSequence(seed, spawn_key=(N, r, stream))."),
    ("data_dir", Optional[str], default(Spec, "data_dir"), "--data-dir", DATA_DIR_HELP),
    ("dvl_noise", float, default(CorruptionConfig, "dvl_noise"), "--dvl-noise", "Synthetic DVL noise std [m/s]."),
    ("misalignment_deg", float, default(CorruptionConfig, "misalignment_deg"), "--misalignment-deg", "Initial misalignment std per axis [deg]."),
    ("heading_deg", Optional[float], default(CorruptionConfig, "heading_deg"), "--heading-deg", "Initial heading (yaw-axis) misalignment std [deg]; default: --misalignment-deg."),
    ("vel_h_std", float, default(CorruptionConfig, "vel_h_std"), "--vel-h-std", "Initial north/east velocity error std [m/s]."),
    ("vel_v_std", float, default(CorruptionConfig, "vel_v_std"), "--vel-v-std", "Initial down velocity error std [m/s]."),
    ("acc_noise", float, default(CorruptionConfig, "acc_noise"), "--acc-noise", "Accelerometer white noise std per 100 Hz sample [m/s^2]."),
    ("gyro_noise", float, default(CorruptionConfig, "gyro_noise"), "--gyro-noise", "Gyro white noise std per sample [rad/s]."),
    ("acc_bias", float, default(CorruptionConfig, "acc_bias"), "--acc-bias", "Accelerometer bias std [m/s^2]."),
    ("gyro_bias", float, default(CorruptionConfig, "gyro_bias"), "--gyro-bias", "Gyro bias std [rad/s]."),
    ("pos_h_std", float, default(CorruptionConfig, "pos_h_std"), "--pos-h-std", "Initial north/east position error std [m] (0 in the papers; with --state 15 the filter's P0 follows it)."),
    ("pos_v_std", float, default(CorruptionConfig, "pos_v_std"), "--pos-v-std", "Initial down position error std [m]."),
]

RECORDED = [  # corrections of recorded data (docs/checking-data.md): mc, sweep, run, train
    ("imu_axes", str, default(Spec, "imu_axes"), "--imu-axes", "Recorded IMU axis mapping: corrected body axis i is the i-th signed recorded axis, e.g. x,-y,z (nespm check finds it)."),
    ("imu_time_offset", float, default(Spec, "imu_time_offset"), "--imu-time-offset", "Recorded IMU stamp minus GT time [s]; subtracted from the IMU stamps (nespm check measures it)."),
    ("imu_time_drift", float, default(Spec, "imu_time_drift"), "--imu-time-drift", "Recorded IMU clock drift [s/s]: stamp - GT time = offset + drift * GT time (nespm check measures it)."),
    ("dvl_time_offset", float, default(Spec, "dvl_time_offset"), "--dvl-time-offset", "DVL stamp minus GT time [s]; the DVL is re-sampled at the GT epochs from its shifted stamps."),
    ("window", Optional[str], default(Spec, "window"), "--window", "START:END [s, GT file time]: use only these GT epochs of every track (e.g. 20:400)."),
    ("corrections", Optional[str], default(Spec, "corrections"), "--corrections", "Per-track corrections (imu_axes, offsets, window) from the corrections.json that 'nespm check' writes; an option given explicitly overrides it for every track."),
]

KERNELS = ("kernels", Optional[str], None, "--kernels",
            "The filters' IMU-rate loop: auto (compiled with numba where installed), numba, or numpy (the "
            "reference); default $NESPM_KERNELS, else auto. The same numbers to round-off either way (docs/architecture.md); not part of an "
            "experiment's identity, like --jobs.")

#: --accept-residual (run, mc, sweep, tune through COMMON; corrupt, train, tracks): a track whose data contradict
#: its declared conventions (docs/data-format.md) runs anyway
ACCEPT_RESIDUAL = ("accept_residual", bool, default(Spec, "accept_residual"), ACCEPT_RESIDUAL_FLAG, ACCEPT_RESIDUAL_HELP)

COMMON = [  # the options that define an experiment: the realizations, the data, the filters
    *CORRUPTION,
    ACCEPT_RESIDUAL,
    ("data_warnings", str, "warn", "--data-warnings", "Data that looks wrong but may be legitimate (irregular epoch steps, fast turns, a DVL speed far from the GT's, ...): warn (one line each), ignore, or error (exit 2). Clear mistakes are always errors."),
    ("scenario", str, default(Spec, "scenario"), "--scenario", "nominal, or outage: no DVL for --outage-length s from --outage-start s."),
    ("state", str, default(FilterConfig, "state"), "--state", "Error-state layout: 12 (the papers': velocity, attitude, biases), 15 (position first) or a comma list of blocks from pos,vel,att,ba,bg (docs/sensors.md)."),
    ("sensors_", str, ",".join(default(Spec, "sensors")), "--sensors", "Comma list of measurement sources, applied in this order at equal times: dvl, depth, fix, dvl-beams, heading, or a plugin's (docs/sensors.md)."),
    ("filter_option", Optional[List[str]], None, "--filter-option", "NAME.KEY=VALUE for a filter of --filters: a plugin's own option (its option_defaults), a sigma-point filter's alpha, beta, kappa (ukf.alpha=0.5), or a noise scale of any filter with a covariance (ekf.acc_noise_scale=2, ekf.r_scale_dvl=0.5; docs/tuning.md) or a sensor's lever arm in its model (ekf.lever_arm_x_dvl=-1.6 [m]); repeatable; [filters.NAME] tables in a --config file; recorded in the manifest, part of the experiment (docs/plugins.md)."),
    ("sensor_option", Optional[List[str]], None, "--sensor-option", "NAME.KEY=VALUE for a sensor of --sensors, e.g. fix.interval=10, fix.std=1, depth.std=0.05, dvl.outage=180:200; repeatable; [sensors.NAME] tables in a --config file."),
    ("sensor_plugins", Optional[List[str]], None, "--sensor-plugin", "A Python file (or module) defining your own sensors with nespm_cli.sensors.register; repeatable; then name them in --sensors (docs/sensors.md)."),
    ("imu_rate", float, default(Spec, "imu_rate"), "--imu-rate", "Rate of the synthesized IMU [Hz]: round(rate x GT step) steps per GT interval (the noise std options are per sample at this rate)."),
    ("imu", str, default(Spec, "imu"), "--imu", "synthetic (inverse strapdown of GT: exact truth) or recorded (IMU_trajectoryN.csv)."),
    *RECORDED,
    ("dvl", str, default(Spec, "dvl"), "--dvl", "recorded (the track's DVL file) or synthetic (C_n^b v + w_nb x l + N(0, dvl-noise^2))."),
    ("dvl_lever_arm", Tuple[float, float, float], default(Spec, "dvl_lever_arm"), "--dvl-lever-arm", "DVL lever arm X Y Z [m, body] in the measurement model (and in synthetic DVL)."),
    ("dvl_r_std", Optional[float], default(Spec, "dvl_r_std"), "--dvl-r-std", "Filter DVL std [m/s] (default 0.02 with synthetic DVL, 0.1 with recorded)."),
    ("outage_start", float, default(Spec, "outage_start"), "--outage-start", "Outage start [s after the first epoch]."),
    ("outage_length", float, default(Spec, "outage_length"), "--outage-length", "Outage length [s]."),
    ("diverge_att_deg", float, default(DivergenceRule, "att_deg"), "--diverge-att-deg", "A run counts as diverged when its attitude error exceeds this [deg] after --diverge-after (also: non-finite state, speed > 50 m/s)."),
    ("diverge_nees", float, default(DivergenceRule, "nees"), "--diverge-nees", "...or when its NEES averaged over --diverge-window s exceeds this after --diverge-after (6-dof chi-square 99.9 %: 22.5)."),
    ("diverge_window", float, default(DivergenceRule, "window_s"), "--diverge-window", "Window of the NEES divergence test [s]."),
    ("diverge_after", float, default(DivergenceRule, "after_s"), "--diverge-after", "Seconds after the start before the attitude and NEES tests apply (initial errors may be large)."),
    ("filter_acc_noise", Optional[float], None, "--filter-acc-noise", "Accelerometer white noise std per sample in the filters' Q [m/s^2]; default: the injected --acc-noise. With a recorded IMU add its own noise in quadrature (nespm check measures it)."),
    ("filter_gyro_noise", Optional[float], None, "--filter-gyro-noise", "Gyro white noise std per sample in the filters' Q [rad/s]; default: the injected --gyro-noise (see --filter-acc-noise)."),
    ("acc_bias_rw", float, default(FilterConfig, "acc_bias_rw"), "--acc-bias-rw", "Filter accelerometer bias random walk [m/s^2/sqrt(s)]."),
    ("gyro_bias_rw", float, default(FilterConfig, "gyro_bias_rw"), "--gyro-bias-rw", "Filter gyro bias random walk [rad/s/sqrt(s)]."),
    ("alpha", float, default(FilterConfig, "alpha"), "--alpha", "UKF sigma-point spread alpha (beta = 2, kappa = 0)."),
    ("filter_plugins", Optional[List[str]], None, "--filter-plugin", "A Python file (or module) defining your own filters with nespm_cli.filters.registry.register; repeatable; then name them in --filters (docs/plugins.md)."),
    ("weights", Optional[str], default(Spec, "weights"), ("--noise-model", "--weights"), "Noise model of anekf/anukf/anukf-nespm: ProcessNet weights (.npz from 'nespm train'), an ONNX model (.onnx; pip install 'nespm[onnx]') or a plugin's file (docs/learned.md); default: the packaged ProcessNet (embedded tracks 1-4)."),
    ("tau", Optional[float], default(FilterConfig, "tau"), "--tau", "Adaptive Q, eqs 44/46: q = std^2 * tau [s]; default: the IMU step."),
    ("tau_a", Optional[float], default(FilterConfig, "tau_a"), "--tau-a", "Adaptive Q, eq 45: q_v = q_a * tau_a [s]; default: the time-update span."),
    ("tau_g", Optional[float], default(FilterConfig, "tau_g"), "--tau-g", "Adaptive Q, eq 47: q_psi = q_g * tau_g [s]; default: the time-update span."),
    ("adaptive_bias", str, default(FilterConfig, "adaptive_bias"), "--adaptive-bias", "Adaptive Q bias blocks: nominal (the fixed random walk), scaled (x (std/nominal)^2, matches --dynamic-bias segment) or paper (q_a, q_g of eq 43)."),
    ("q_clip", Tuple[float, float], default(FilterConfig, "q_clip"), "--q-clip", "Validity bounds LOW HIGH on the network std, as multiples of the nominal std."),
    ("time_update", str, default(FilterConfig, "time_update"), "--time-update", "dvl: one time update per DVL interval (sigma points carried through all its IMU steps); imu: every IMU step."),
]


PARALLEL = [  # where the chunks of a resumable experiment run (mc, sweep, gp-ukf)
    ("jobs", int, 2, "--jobs", "Local worker processes: loky, or the local Dask cluster (results do not depend on it)."),
    ("backend", str, "loky", "--backend", "Where chunks run: loky (local processes) or dask (a Dask cluster; pip install 'nespm[dask]')."),
    ("scheduler", Optional[str], None, "--scheduler", "Dask scheduler address (tcp://host:8786) or scheduler file; default $NESPM_DASK_SCHEDULER, else a local cluster of --jobs workers (docs/cluster.md)."),
    ("no_progress", bool, False, "--no-progress", "No progress (a bar on a terminal, else a line on stderr every 15 s with the ETA)."),
    KERNELS,
]

RUNNER = [  # options of the commands that run many realizations (mc, sweep)
    ("tracks_", str, " ".join(map(str, default(Spec, "tracks"))), "--tracks", "Track numbers: --tracks 5 6 or --tracks 5,6."),
    ("runs", int, default(Spec, "runs"), "--runs", "Monte Carlo runs per track."),
    ("filters_", str, ",".join(default(Spec, "filters")), "--filters", f"Comma list of {', '.join(FILTERS)} (docs/filters.md), or a plugin's."),
    ("chunk_size", Optional[int], default(Spec, "chunk_size"), "--chunk-size", "Runs per batch, the resumable unit (no number depends on it). Default: a folder that holds results keeps its own; else each track's runs are split so that --jobs workers have work, at most 50 per chunk (--tracks 5 --runs 8 --jobs 2: 2 chunks of 4)."),
    ("smooth_", str, "", "--smooth", f"Comma list of filters of --filters ({', '.join(SMOOTHABLE)}) whose fixed-interval RTS-smoothed solution is reported too, as <filter>-rts: the hindsight floor, on the same runs (docs/filters.md)."),
    ("save_series", str, default(Spec, "save_series"), "--save-series", "Per-run series kept in chunks/: norms (error norms, block NEES, coverage, NIS; ~100 B per run, epoch and filter) or axes (also every state component's error and std, ~330 B; adds the per-axis RMS/sigma and the noncredibility index to epochs.parquet; docs/results-schema.md)."),
    ("config", Optional[str], None, "--config", "TOML file of options (keys are option names: runs = 100, tracks = [5, 6]); options on the command line override it. See experiments/."),
    *PARALLEL,
]

IMU = [o for o in COMMON if o[0] == "imu"]


def with_options(*groups):
    """Give a command (which takes ``**kw``) the options of ``groups`` after its own."""
    def deco(f):
        own = [p for p in inspect.signature(f).parameters.values() if p.kind != p.VAR_KEYWORD]
        extra = [inspect.Parameter(n, inspect.Parameter.KEYWORD_ONLY, annotation=t,
                                   default=typer.Option(d, *((flag,) if isinstance(flag, str) else flag), help=h,
                                                        show_default=d is not None))
                 for group in groups for n, t, d, flag, h in group]

        @functools.wraps(f)
        def wrapper(**kwargs):
            if "kernels" in kwargs:  # for this process and the workers it starts (they inherit it)
                from nespm_cli.filters.kernels import kernel_mode, set_kernel_mode

                mode = kwargs.pop("kernels")
                set_kernel_mode(kernel_mode() if mode is None else mode)
            return f(**kwargs)

        wrapper.__signature__ = inspect.Signature(own + extra)
        return wrapper
    return deco
