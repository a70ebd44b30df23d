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
