"""Option values into library objects: track and filter lists, the corruption, the Spec of the
common options, the Execution of the parallel options. Every coupling of options lives in the
library (experiments.spec.validate), not here. Light at import (the config classes are imported by
the functions that build them), so ``nespm tracks`` uses :func:`warning_mode` without the filters."""
from __future__ import annotations

import re
from typing import TYPE_CHECKING, Optional

from nespm_cli.cli.config import ARGV, GIVEN
from nespm_cli.errors import NespmError

if TYPE_CHECKING:
    from nespm_cli.data.corruption import CorruptionConfig


def parse_tracks(text: str) -> tuple[int, ...]:
    try:
        out = tuple(int(x) for x in text.replace(",", " ").split())
    except ValueError:
        raise NespmError(f"--tracks: expected track numbers like '5 6' or '5,6', got {text!r}") from None
    if not out:
        raise NespmError("--tracks: give at least one track number")
    return out


def parse_filters(text: str) -> tuple[str, ...]:
    return tuple(x.strip().lower() for x in text.split(",") if x.strip())


#: option name -> field of the config dataclass it sets (where the names differ, or the class)
CORRUPTION_FIELDS = {"schedule": "schedule", "segment_length": "segment_s", "dynamic_bias": "dynamic_bias",
                     "dvl_noise": "dvl_noise", "misalignment_deg": "misalignment_deg", "heading_deg": "heading_deg",
                     "vel_h_std": "vel_h_std", "vel_v_std": "vel_v_std", "acc_noise": "acc_noise",
                     "gyro_noise": "gyro_noise", "acc_bias": "acc_bias", "gyro_bias": "gyro_bias",
                     "pos_h_std": "pos_h_std", "pos_v_std": "pos_v_std"}
FILTER_FIELDS = ("acc_bias_rw", "gyro_bias_rw", "alpha", "tau", "tau_a", "tau_g", "adaptive_bias", "q_clip",
                 "time_update", "state")


def corruption_config(kw: dict) -> CorruptionConfig:
    """Pop the corruption options (:data:`CORRUPTION_FIELDS`) from ``kw``."""
    from nespm_cli.data.corruption import CorruptionConfig

    return CorruptionConfig(**{field: kw.pop(opt) for opt, field in CORRUPTION_FIELDS.items()})


def warning_mode(mode: str) -> None:
    from nespm_cli.data.plausibility import set_warning_mode

    if mode not in ("warn", "ignore", "error"):
        raise NespmError(f"--data-warnings: choose warn, ignore or error, got {mode!r}")
    set_warning_mode(mode)


def parse_sensor_option(text: str, flag: str = "--sensor-option") -> tuple[str, str, str]:
    """``NAME.KEY=VALUE`` -> ``(NAME, KEY, VALUE)`` (one-line error otherwise)."""
    m = re.fullmatch(r"\s*([A-Za-z0-9_-]+)\.([A-Za-z0-9_]+)\s*=(.*)", text)
    if not m:
        example = "fix.interval=10" if flag == "--sensor-option" else "ukf.alpha=0.5"
        raise NespmError(f"{flag} {text!r}: expected NAME.KEY=VALUE, e.g. {example}")
    return m.group(1), m.group(2), m.group(3).strip()


def build_spec(**kw):
    """The Spec of the common options; every coupling of options (P0 from the corruption, the DVL
    flags as the DVL's options) happens in the library (experiments.spec.validate), not here."""
    from nespm_cli.experiments.metrics import DivergenceRule
    from nespm_cli.experiments.spec import Spec
    from nespm_cli.filters import FilterConfig

    warning_mode(kw.pop("data_warnings"))
    corr = corruption_config(kw)
    kw["filter_plugins"] = tuple(kw.get("filter_plugins") or ())
    kw["sensor_plugins"] = tuple(kw.get("sensor_plugins") or ())
    kw["sensors"] = tuple(s.strip() for s in kw.pop("sensors_").split(",") if s.strip())
    kw["sensor_options"] = tuple(parse_sensor_option(o) for o in kw.pop("sensor_option") or ())
    kw["filter_options"] = tuple(parse_sensor_option(o, "--filter-option") for o in kw.pop("filter_option") or ())
    if "smooth_" in kw:  # mc, sweep
        kw["smooth"] = tuple(f.strip().lower() for f in kw.pop("smooth_").split(",") if f.strip())
    kw["given"] = tuple(sorted(GIVEN))
    GIVEN.clear()  # this command line's: a later build_spec without a new command line has none
    fields = {k: kw.pop(k) for k in FILTER_FIELDS}
    fcfg = FilterConfig(**{**fields, "q_clip": tuple(fields["q_clip"])})
    kw["divergence"] = DivergenceRule(att_deg=kw.pop("diverge_att_deg"), nees=kw.pop("diverge_nees"),
                                      window_s=kw.pop("diverge_window"), after_s=kw.pop("diverge_after"))
    return Spec(corruption=corr, filter_config=fcfg, **kw)


def check_jobs(jobs: int) -> int:
    """``--jobs``: one rule for every command (mc, sweep, gp-ukf, tune): at least 1 worker, else one line."""
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise NespmError(f"--jobs must be at least 1, got {jobs}")
    return jobs


def execution(jobs: int, backend: str, scheduler: Optional[str], no_progress: bool):
    """The Execution of the parallel options (where the chunks run; no number depends on it)."""
    from nespm_cli.experiments.backend import Execution

    check_jobs(jobs)
    return Execution(jobs=jobs, backend=backend, scheduler=scheduler, progress=not no_progress,
                     argv=("nespm", *ARGV))
