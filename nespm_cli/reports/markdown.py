"""Markdown of the reports: tables, number / percent / interval formatting, the run header line,
the link to the definitions (docs/report.md)."""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
import pandas as pd

from nespm_cli.reports.results import filters_in_order, runs_per_track, unique_text

DASH = "—"
SIG_MARK = "*"
SMALL_MARK = "†"


def fmt(x: Any, spec: str = ".4g") -> str:
    """Format a number, or an em dash for None/NaN."""
    if x is None or (isinstance(x, (float, np.floating)) and not np.isfinite(x)):
        return DASH
    return format(x, spec)


def pct(x: float) -> str:
    """One decimal like the papers (21.3), more where that would print 0.0 or -0.0."""
    if abs(x) >= 0.05 or x == 0.0:
        return f"{x:.1f}"
    return f"{x:.2g}" if abs(x) >= 1e-4 else f"{x:.1e}"


def fmt_pct(x: Any) -> str:
    """Improvement in percent, e.g. ``21.3 %`` (small values keep two significant digits)."""
    return DASH if x is None or not np.isfinite(x) else f"{pct(x)} %"


MAX_DECIMALS = 10


def decimals(point: float, lo: float, hi: float) -> int:
    """Decimals for an interval and its point: two significant digits of the interval width
    (at least one decimal, as the papers), more until distinct values print distinctly, but only as far
    as :data:`MAX_DECIMALS` can tell them apart. A width that does not show at :data:`MAX_DECIMALS`
    (an exact 0 beside a round-off interval of ±1e-15) is no width: the decimals are then those of the
    values themselves, one for a zero (``0.0 % [0.0, 0.0]``, as :func:`fmt_pct` prints 0), more until a
    non-zero value shows its first digit."""
    vals = [v for v in (point, lo, hi) if v is not None and np.isfinite(v)]
    width = abs(hi - lo) if np.isfinite(lo) and np.isfinite(hi) else 0.0
    d = max(1, math.ceil(-math.log10(width)) + 1) if width > 0 else 1
    if d > MAX_DECIMALS:  # the width does not show: the decimals of the largest value
        big = max((abs(v) for v in vals), default=0.0)
        d = 1
        while d < MAX_DECIMALS and float(fixed(big, d)) == 0.0 < float(fixed(big, MAX_DECIMALS)):
            d += 1

    def shown(k: int) -> int:
        return len({fixed(v, k) for v in vals})

    most = shown(MAX_DECIMALS)  # the distinctions MAX_DECIMALS can show at all
    while d < MAX_DECIMALS and shown(d) < most:
        d += 1
    return d


def fixed(x: float, d: int) -> str:
    """``x`` with ``d`` decimals, without a minus sign on a value that prints as zero."""
    t = f"{x:.{d}f}"
    return t[1:] if t.startswith("-") and float(t) == 0.0 else t


def fmt_imprv(point: float, lo: float, hi: float, mark: str = "") -> str:
    """``point % [lo, hi]`` (+ `` mark``) with the decimals of :func:`decimals`, e.g.
    ``-0.0076 % [-0.0091, -0.0061] *``; just the point without a finite interval."""
    if point is None or not np.isfinite(point):
        return DASH
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return fmt_pct(point)
    d = decimals(point, lo, hi)
    return f"{fixed(point, d)} % [{fixed(lo, d)}, {fixed(hi, d)}]" + (f" {mark}" if mark else "")


def imprv_cells(point: float, lo: float, hi: float, mark: str = "") -> tuple[str, str]:
    """The main table's two cells ``point %`` and ``[lo, hi] mark`` with shared decimals."""
    if point is None or not np.isfinite(point):
        return DASH, DASH
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return fmt_pct(point), DASH
    d = decimals(point, lo, hi)
    return f"{fixed(point, d)} %", f"[{fixed(lo, d)}, {fixed(hi, d)}]" + (f" {mark}" if mark else "")


def fmt_ci(lo: float, hi: float, excludes_0: bool | str) -> str:
    """``[lo, hi] %`` with the decimals of :func:`decimals` and a trailing mark: ``*`` when
    ``excludes_0`` is True, or the given mark string (``*``, ``†`` or ``""``)."""
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return DASH
    mark = excludes_0 if isinstance(excludes_0, str) else (SIG_MARK if excludes_0 else "")
    d = decimals(math.nan, lo, hi)
    return f"[{fixed(lo, d)}, {fixed(hi, d)}] %" + (f" {mark}" if mark else "")


def md_table(headers: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A GitHub-flavoured markdown table."""
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join(" --- " for _ in headers) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def inputs_text(manifest: dict) -> str:
    """`` (N input files, sha256 ...)``: which data a table came from (the manifest's ``inputs``)."""
    import hashlib

    inputs = manifest.get("inputs") or {}
    if not inputs:
        return ""
    digest = hashlib.sha256("".join(f"{k}={v}\n" for k, v in sorted(inputs.items())).encode()).hexdigest()
    return f" ({len(inputs)} input files; sha256 of their hashes {digest[:12]}, per file in manifest.json)"


def layout_text(manifest: dict) -> str:
    """The error-state layout the filters ran with (``--state``): the manifest's option, else its
    ``filter_config`` cells' ``state`` (several joined), else — (a folder written before it)."""
    options = manifest.get("options") or {}
    if options.get("state"):
        return str(options["state"])
    cells = manifest.get("filter_config") or {}
    states = [str(c["state"]) for c in cells.values() if isinstance(c, dict) and c.get("state")]
    return ", ".join(dict.fromkeys(states)) or DASH


SCENARIO_KEYS = ("noise_schedule", "outliers")  # the sensor options a Run line names when set


def sensors_text(manifest: dict) -> str:
    """The sensors of the study (``--sensors``) in update order with their source and noise scenario
    (``dvl (noise_schedule step:0=1,120=4, synthetic)``),
    from the manifest's options and ``sensors`` cells; — when it records none."""
    names = list((manifest.get("options") or {}).get("sensors") or [])
    cells = [c for c in (manifest.get("sensors") or {}).values() if isinstance(c, dict)]
    for c in cells:
        names += [n for n in c if n not in names]
    if not names:
        return DASH

    def source(n: str) -> str:
        got = {str(c[n].get("source")) for c in cells if isinstance(c.get(n), dict) and c[n].get("source")}
        for key in SCENARIO_KEYS:  # a noise scenario (docs/sensors.md): its spec as given
            got |= {f"{key} {c[n][key]}" for c in cells if isinstance(c.get(n), dict) and c[n].get(key)}
        return f" ({', '.join(sorted(got))})" if got else ""

    return ", ".join(n + source(n) for n in names)


def header_line(metrics: pd.DataFrame, manifest: dict) -> str:
    """The run summary line: tracks, runs per track, filters, error-state layout, sensors, IMU, scenario,
    schedule, seed, data, time."""
    options = manifest.get("options") or {}

    def field(col: str) -> str:
        if col in metrics.columns:
            return unique_text(metrics[col])
        return str(options.get(col, manifest.get(col, DASH)))

    seed = manifest.get("seed", None)
    seed_text = str(seed) if seed is not None else field("seed")
    wall = manifest.get("wall_seconds")
    wall_text = f"{float(wall):.1f} s" if isinstance(wall, (int, float)) else DASH
    parts = [
        f"tracks {', '.join(str(t) for t in sorted(pd.unique(metrics['track'])))}",
        f"runs per track {runs_per_track(metrics)}",
        f"filters {', '.join(filters_in_order(metrics))}",
        f"error state {layout_text(manifest)}",
        f"sensors {sensors_text(manifest)}",
        f"imu {options.get('imu', DASH)}",
        f"scenario {field('scenario')}",
        f"schedule {field('schedule')}",
        f"seed {seed_text}",
        f"data dir {manifest.get('data_dir') or DASH}" + inputs_text(manifest),
        f"wall time {wall_text}",
    ]
    return "**Run:** " + "; ".join(parts) + "."


#: the page that defines every column and figure of the reports
REPORT_DOCS = Path(__file__).resolve().parents[2] / "docs" / "report.md"


def docs_line(out_dir: Path) -> str:
    """The one line linking a report in ``out_dir`` to docs/report.md: a relative link when the report lies inside
    the nespm sources (it then holds in any clone and on a forge), the page's absolute path on this machine when
    it lies outside them (a relative path out of ``/tmp`` climbs to ``/`` and breaks once the folder is moved or
    copied), the page's name when the sources are not on this machine (an installed wheel has no docs/)."""
    if REPORT_DOCS.is_file():
        out, root = Path(out_dir).resolve(), REPORT_DOCS.parents[1]
        target = (Path(os.path.relpath(REPORT_DOCS, out)).as_posix() if out.is_relative_to(root)
                  else REPORT_DOCS.as_posix())
        target = f"<{target}>" if " " in target else target
        return f"Every column, figure and word of this report is defined in [docs/report.md]({target})."
    return "Every column, figure and word of this report is defined in docs/report.md of the nespm sources."
