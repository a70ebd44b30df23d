"""Figure helpers shared by the reports: saving, filter colours, DVL-outage spans."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np


FIG_DPI = 150


def save_figure(fig, path: Path, dpi: int = FIG_DPI) -> Path:
    """Lay out, write ``path`` (PNG) and close ``fig``; return ``path``. Every report figure ends here."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
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


def filter_colors(filters: Sequence[str]) -> dict[str, Any]:
    """One tab10 colour per filter, stable across figures."""
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    return {f: cmap(i % 10) for i, f in enumerate(filters)}
