"""Figures of ProcessNet training (``nespm train``): the loss curves."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nespm_cli.reports.figures import save_figure, use_agg


def plot_history(hists: dict, path, tests: dict | None = None) -> Path:
    """Loss curves (train and validation, log y) of every sensor, one panel each."""
    use_agg()
    import matplotlib.pyplot as plt

    path = Path(path)
    fig, axes = plt.subplots(1, len(hists), figsize=(5 * len(hists), 3.6), squeeze=False)
    for ax, (s, h) in zip(axes[0], hists.items()):
        ep = np.arange(1, len(h["train_loss"]) + 1)
        ax.plot(ep, h["train_loss"], "o-", label="train")
        ax.plot(ep, h["val_loss"], "s-", label="validation")
        ax.axvline(h["best_epoch"] + 1, color="0.6", ls=":", label="best (restored)")
        ax.set_yscale("log")
        ax.set_xlabel("epoch")
        ax.set_ylabel("MSE loss (eq 42, normalized std²)")
        title = f"{s} ProcessNet"
        if tests and s in tests:
            title += f" — test Spearman {tests[s]['spearman']:.3f}"
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    return save_figure(fig, path, dpi=110)


# ----------------------------------------------------------------------------- inference
