"""The words of the reports' verdicts: a metric's verdict over its comparisons in a few words
(:func:`verdict_headline`) and the word of one comparison (:data:`SHORT_VERDICT`), from the verdicts
of :func:`nespm_cli.reports.comparisons.compare_filters`. docs/report.md defines each."""
from __future__ import annotations

import pandas as pd

__all__ = ["SHORT_VERDICT", "verdict_headline"]

#: the word of one comparison, by its ``compare_filters`` verdict
SHORT_VERDICT = {
    "better": "meaningful",
    "worse": "meaningful (the other is better)",
    "no practical difference": "no practical difference",
    "not significant": "not significant",
    "too few runs": "too few paired runs",
    "undefined": "undefined",
}


def verdict_headline(comps: pd.DataFrame) -> str:
    """The verdict of one metric's comparisons (its rows of ``compare_filters``) in a few words."""
    best = comps["best"].iloc[0]
    undefined = [o for o, w in zip(comps["other"], comps["verdict"]) if w == "undefined"]
    if undefined and len(undefined) < len(comps):  # judged on the comparisons that could be formed
        words = verdict_headline(comps[comps["verdict"] != "undefined"])
        return words + f"; against {', '.join(f'`{o}`' for o in undefined)} undefined (no run kept by both)"
    v = set(comps["verdict"])
    if "better" in v:
        tied = [o for o, w in zip(comps["other"], comps["verdict"]) if w == "no practical difference"]
        if tied:
            return (f"best: `{best}` and {', '.join(f'`{o}`' for o in tied)} "
                    "(no practical difference between them)")
        return f"`{best}` is best" + (" (meaningfully better than every other filter)" if v == {"better"} else "")
    if v == {"no practical difference"}:
        return "no practical difference between the filters"
    if "too few runs" in v and v <= {"too few runs", "no practical difference"}:
        return "not assessed (too few paired runs)"
    return "no clear winner"


#: the blocks of the 6-DOF NEES ([δv, δψ]) in the per-block table (:func:`block_consistency.block_consistency`)
NEES_BLOCKS = ("vel", "att")


def mean_nees_place(mean: float, lo: float, hi: float) -> str:
    """Where a mean NEES lies against its 95 % band: ``above``, ``below``, ``inside``, or ``""`` (no number).
    A place, not a judgement: a filter's consistency is judged per block and sensor (docs/report.md)."""
    if not (mean == mean and lo == lo and hi == hi):
        return ""
    return "above" if mean > hi else "below" if mean < lo else "inside"


def block_cause(rows: pd.DataFrame, place: str) -> str:
    """The block that drives a mean NEES ``place`` (``above`` or ``below``) its band, from one filter's rows of the
    per-block table (``item``, ``name``, ``mean``, ``dof``, ``above``, ``below``, ``word``): of the 6-DOF NEES's
    blocks (:data:`NEES_BLOCKS`), the one whose mean ANEES is farthest from its dof that way, e.g. ``velocity
    (mean ANEES 4.2 of 3; 23 % of its epochs above the bounds, 71 % below: a few epochs far above pull the mean
    up)``; "" without such a block."""
    r = rows[rows["item"].isin(NEES_BLOCKS)] if len(rows) else rows
    if place not in ("above", "below") or r.empty:
        return ""
    ratio = r["mean"].astype(float) / r["dof"].astype(float)
    b = r.loc[ratio.idxmax() if place == "above" else ratio.idxmin()]
    if (place == "above" and b["mean"] <= b["dof"]) or (place == "below" and b["mean"] >= b["dof"]):
        return ""
    text = (f"{b['name']} (mean ANEES {b['mean']:.3g} of {int(b['dof'])}; {100 * b['above']:.0f} % of its epochs above "
            f"the bounds, {100 * b['below']:.0f} % below")
    if place == "above" and b["below"] > b["above"]:
        text += ": a few epochs far above pull the mean up"
    elif place == "below" and b["above"] > b["below"]:
        text += ": a few epochs far below pull the mean down"
    return text + ")"


def mean_nees_words(mean: float, lo: float, hi: float, cause: str = "") -> str:
    """The one wording of a mean 6-DOF NEES beside the per-block judgement: ``mean NEES 9.5 above its band
    [3.84, 8.63], driven by velocity (...)`` (``cause`` of :func:`block_cause`), ``... inside its band ...``;
    "" without a number."""
    place = mean_nees_place(mean, lo, hi)
    if not place:
        return ""
    return f"mean NEES {mean:.3g} {place} its band [{lo:.2f}, {hi:.2f}]" + (f", driven by {cause}" if cause else "")


__all__ += ["NEES_BLOCKS", "block_cause", "mean_nees_place", "mean_nees_words"]
