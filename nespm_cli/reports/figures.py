"""Figure helpers shared by the reports: the Agg backend, saving, what a figure drew (:class:`Drawn`),
filter colours and line styles, DVL-outage spans and shading, mean ± std bands, log-axis choices."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

FIG_DPI = 150
LINE_STYLES = ("-", "--", "-.", ":")


@dataclass(frozen=True)
class Drawn:
    """A figure written to ``path`` and the numbers it drew: ``data`` holds one row per point with
    columns ``panel`` (str), ``series`` (str), ``x``, ``y`` (float, in the units of the axes)."""

    path: Path
    data: pd.DataFrame


def drawn_rows(panel: str, series: str, x: Any, y: Any) -> pd.DataFrame:
    """The :class:`Drawn` rows of one plotted series."""
    x, y = np.asarray(x, dtype=float).ravel(), np.asarray(y, dtype=float).ravel()
    return pd.DataFrame({"panel": panel, "series": series, "x": x, "y": y})


def drawn(path: Path, parts: Sequence[pd.DataFrame]) -> Drawn:
    """A :class:`Drawn` from the rows of every plotted series."""
    data = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=["panel", "series", "x", "y"])
    return Drawn(Path(path), data)


def use_agg() -> None:
    """Select the file-only Agg backend (before pyplot draws anything): reports never open a window."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401  (after selecting the backend)


def save_figure(fig, path: Path, dpi: int = FIG_DPI) -> Path:
    """Lay out, write ``path`` (PNG; legends outside the axes included) and close ``fig``; return
    ``path``. Every report figure ends here."""
    import matplotlib.pyplot as plt

    from nespm_cli.experiments.progress import phase

    phase(f"figures: writing {Path(path).name}")
    fig.tight_layout()
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return Path(path)


def outage_spans(t: np.ndarray, dvl_used: np.ndarray) -> list[tuple[float, float]]:
    """Time spans of consecutive epochs with t > 0 and no DVL update (half-epoch padded)."""
    mask = (~dvl_used) & (t > 0)
    spans = []
    i, n = 0, len(t)
    while i < n:
        if not mask[i]:
            i += 1
            continue
        j = i
        while j + 1 < n and mask[j + 1]:
            j += 1
        lo = 0.5 * (t[i - 1] + t[i]) if i > 0 else t[i]
        hi = 0.5 * (t[j] + t[j + 1]) if j + 1 < n else t[j]
        spans.append((float(lo), float(hi)))
        i = j + 1
    return spans


def shade_outages(ax, t: np.ndarray, dvl_used: np.ndarray, label: bool = True) -> None:
    """Grey spans where no DVL update was applied (:func:`outage_spans`), labelled once."""
    for k, (lo, hi) in enumerate(outage_spans(np.asarray(t, float), np.asarray(dvl_used, bool))):
        ax.axvspan(lo, hi, color="0.6", alpha=0.3, lw=0, label="DVL outage" if k == 0 and label else None)


def filter_colors(filters: Sequence[str]) -> dict[str, Any]:
    """One tab10 colour per filter, stable across figures."""
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    return {f: cmap(i % 10) for i, f in enumerate(filters)}


def line_style(i: int) -> dict[str, Any]:
    """Line style and width of the i-th curve of a panel: later curves dashed and thinner, so that
    curves which coincide (filters with the same errors) stay visible."""
    return {"ls": LINE_STYLES[i % len(LINE_STYLES)], "lw": max(2.2 - 0.45 * i, 0.9)}


def mean_std_band(ax, t: Any, mean: Any, std: Any, color: Any, label: str, **line: Any) -> None:
    """A mean line and its ± 1 std band clipped at 0 (an error norm is never negative)."""
    t, mean, std = (np.asarray(a, dtype=float) for a in (t, mean, std))
    ax.plot(t, mean, color=color, label=label, **({"lw": 1.4} | line))
    ax.fill_between(t, np.clip(mean - std, 0.0, None), mean + std, color=color, alpha=0.2, lw=0)


def legend_outside(ax, **kw: Any) -> None:
    """The legend right of the axes, so that it never covers data."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small", borderaxespad=0.0, **kw)


def use_log_x(values: Sequence[float]) -> bool:
    """Log x-axis when every value is positive and max / min > 100."""
    v = np.asarray([x for x in values if np.isfinite(x)], dtype=float)
    return bool(v.size > 1 and v.min() > 0 and v.max() / v.min() > 100)


def use_log_y(values: Sequence[float] | np.ndarray) -> bool:
    """Log y-axis when the finite positive values span more than one decade."""
    v = np.asarray(values, dtype=float).ravel()
    v = v[np.isfinite(v) & (v > 0)]
    return bool(v.size > 1 and v.max() / v.min() > 10)


def use_log_between(curves: Sequence[Any]) -> bool:
    """Log y-axis when curves lie orders of magnitude apart: the medians of their finite positive
    values span more than a decade (e.g. a free INS beside aided filters; an error growing from
    zero within one curve does not count)."""
    medians = []
    for c in curves:
        v = np.asarray(c, dtype=float).ravel()
        v = v[np.isfinite(v) & (v > 0)]
        if v.size:
            medians.append(float(np.median(v)))
    return use_log_y(medians)
