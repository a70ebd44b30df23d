"""The report of a ``nespm tune`` folder: ``OUT/report.md`` and ``OUT/figures/`` (docs/tuning.md).

Sections: what was tuned on (and whether the held-out tracks overlap it); per filter the default
and tuned training score; the tuned values beside the defaults with their range, importance and
profile (a flat profile: the objective cannot see the parameter); on the held-out runs, per filter
the default against the tuned settings (paired, bootstrap 95 % interval of the improvement, the
ANEES against its band) and the tuned filters against each other (the fair comparison); figures:
convergence (best score so far against trial) and parameter importance.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.data.atomic import write_text_atomic
from nespm_cli.errors import NespmError
from nespm_cli.tuning.heldout import DEFAULT_DIR, TUNED_DIR
from nespm_cli.tuning.profile import FLAT, stopped_short
from nespm_cli.filters.options import TUNED_ON, training_overlap
from nespm_cli.reports.block_consistency import block_consistency, consistency_words
from nespm_cli.reports.figures import save_figure, use_agg
from nespm_cli.reports.markdown import fmt, md_table
from nespm_cli.reports.results import load_results
from nespm_cli.reports.stats import nees_check, paired_bootstrap, paired_improvement, percentile_ci


def is_tune_folder(out_dir: Path) -> bool:
    """Whether ``out_dir`` was written by ``nespm tune`` (it holds ``tune.json``, no ``manifest.json``)."""
    return (Path(out_dir) / "tune.json").is_file() and not (Path(out_dir) / "manifest.json").exists()


def training_caveats(manifest: dict) -> list[str]:
    """The caveats of an ``mc`` folder with tuned filters: which ran with ``nespm tune``'s settings (a
    ranking between tuned filters also reflects their searches), and those run on their own tuning
    realizations."""
    o = manifest.get("options", {}) or {}
    options = [tuple(x) for x in o.get("filter_options", [])]
    tuned = list(dict.fromkeys(x[0] for x in options if x[1] == TUNED_ON))
    out = [f"Tuned settings (nespm tune) for {', '.join(tuned)}: a difference between tuned filters also reflects "
           "how well each search did; the tune report's cross-check (\"Each filter with the others' values\") "
           "says which searches stopped short (docs/tuning.md)."] if len(tuned) > 1 else []
    try:
        lines = training_overlap(options, o.get("seed", 0), o.get("tracks", []), o.get("runs", 0))
    except NespmError:
        return out
    return out + [f"Training numbers: {line}." for line in lines]


def load(out_dir: Path) -> tuple[dict, pd.DataFrame]:
    try:
        record = json.loads((out_dir / "tune.json").read_text(encoding="utf-8"))
        trials = pd.read_parquet(out_dir / "trials.parquet")
    except (OSError, ValueError) as exc:
        raise NespmError(f"{out_dir}: not a finished nespm tune folder ({exc})") from None
    return record, trials


def values_table(record: dict) -> str:
    """Tuned values beside the defaults, with range, importance and profile."""
    rows = []
    for f, b in record["best"].items():
        imp, prof = b.get("importance", {}), b.get("profile", {})
        for p in record["space"][f]:
            k = p["key"]
            pr = prof.get(k)
            seen = "—" if pr is None else ("flat (not seen)" if pr["flat"] else f"{100 * pr['change']:.0f} %")
            shape = b.get("shape", b["values"]).get(k, float("nan"))
            rows.append([f, k, p["kind"], fmt(p["default"]), fmt(shape), fmt(b["values"][k]),
                         f"{fmt(p['low'])}–{fmt(p['high'])}", fmt(imp.get(k, float("nan")), ".2f"), seen])
    return md_table(["filter", "parameter", "acts on", "default", "searched", "tuned (written)", "range", "importance",
                     "profile (score change at x3, /3; linear: ± a third of the range)"], rows)


def level_table(record: dict) -> str:
    """With the fitted level: per filter the level, the training runs it was fitted on, the RMSE and
    ANEES the tuned values give there, and each training track's ANEES ("" without a level)."""
    rows = []
    for f, b in record["best"].items():
        if "at_level" not in b:
            continue
        a = b["at_level"]
        tracks = ", ".join(f"{n}: {fmt(v, '.3g')}" for n, v in b.get("at_level_tracks", {}).items())
        rows.append([f, fmt(float(np.sqrt(b["level"])), ".4g"), str(b["level_runs"]), fmt(a["rmse"]),
                     fmt(a["anees"], ".3g"), tracks])
    if not rows:
        return ""
    return md_table(["filter", "std factor of the level (x every Q, R, P0)", "runs per track", "RMSE",
                     "ANEES (6 dof)", "ANEES per training track"], rows)


def score_table(record: dict, trials: pd.DataFrame) -> str:
    rows = []
    for f, b in record["best"].items():
        t = trials[trials["filter"] == f].set_index("trial")
        d = t.loc[b["default_trial"]] if b.get("default_trial") is not None else None
        best = t.loc[b["trial"]]
        rows.append([f, fmt(b.get("default_score")), fmt(b["score"]), str(b["trial"]),
                     fmt(d["rmse"]) if d is not None else "—", fmt(best["rmse"]),
                     fmt(d["consistency"]) if d is not None else "—", fmt(best["consistency"])])
    return md_table(["filter", "score default", "score tuned", "best trial", "RMSE default", "RMSE tuned",
                     "consistency default", "consistency tuned"], rows)


def heldout_rows(default: pd.DataFrame, tuned: pd.DataFrame, n_boot: int) -> list[list[str]]:
    """Per filter: default vs tuned on the same held-out runs (improvement of tuned, paired interval)."""
    rows = []
    for f in sorted(set(default["filter"]) & set(tuned["filter"]), key=list(default["filter"].unique()).index):
        a, b = f"{f} default", f"{f} tuned"
        m = pd.concat([default[default["filter"] == f].assign(filter=a), tuned[tuned["filter"] == f].assign(filter=b)])
        point = paired_improvement(m, a, b, keys=["vrmse"])["vrmse"]
        lo, hi = percentile_ci(paired_bootstrap(m, a, b, n_boot=n_boot, keys=["vrmse"])["vrmse"])
        cells = [f]
        for part in (default, tuned):
            p = part[(part["filter"] == f) & ~part["diverged"]]
            nees = float(p["nees"].mean())
            blo, bhi, word = nees_check(nees, len(p))
            cells += [fmt(float(np.sqrt(p["sse_vel"].sum() / p["n_samples"].sum()))),
                      f"{fmt(nees, '.3g')} [{fmt(blo, '.3g')}, {fmt(bhi, '.3g')}] {word}"]
        cells += [f"{point:+.1f} % [{lo:+.1f}, {hi:+.1f}]", str(int(default[default['filter'] == f]["diverged"].sum())),
                  str(int(tuned[tuned['filter'] == f]["diverged"].sum()))]
        rows.append(cells)
    return rows


def heldout_consistency(folder: Path) -> dict:
    """Per filter of a held-out mc folder: the per-block consistency words (the mc report's rule: the
    share of epochs inside the 95 % bounds, docs/report.md "Consistency"); {} without per-epoch columns."""
    _, epochs, manifest = load_results(folder)
    if epochs is None:
        return {}
    return consistency_words(block_consistency(epochs, manifest))


def fair_rows(tuned: pd.DataFrame, n_boot: int) -> list[list[str]]:
    """The tuned filters against the most accurate tuned one (paired)."""
    kept = tuned[~tuned["diverged"]]
    rmse = kept.groupby("filter").apply(lambda d: np.sqrt(d["sse_vel"].sum() / d["n_samples"].sum()))
    best = str(rmse.idxmin())
    rows = []
    for f in rmse.sort_values().index:
        if f == best:
            rows.append([f, fmt(float(rmse[f])), "(reference)"])
            continue
        point = paired_improvement(tuned, f, best, keys=["vrmse"])["vrmse"]
        lo, hi = percentile_ci(paired_bootstrap(tuned, f, best, n_boot=n_boot, keys=["vrmse"])["vrmse"])
        rows.append([f, fmt(float(rmse[f])), f"{point:+.1f} % [{lo:+.1f}, {hi:+.1f}]"])
    return rows


def figures(record: dict, trials: pd.DataFrame, fig_dir: Path) -> list[str]:
    """convergence.png (best score so far against trial) and importance.png; their file names."""
    use_agg()
    import matplotlib.pyplot as plt

    fig_dir.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(7, 4))
    for f in record["best"]:
        t = trials[(trials["filter"] == f) & (trials["state"] == "COMPLETE")].sort_values("trial")
        ax.step(t["trial"], np.minimum.accumulate(t["score"].to_numpy()), where="post", label=f)
    ax.set_yscale("log")
    ax.set_xlabel("trial")
    ax.set_ylabel(f"best score so far ({record['objective']})")
    ax.legend()
    save_figure(fig, fig_dir / "convergence.png")
    plt.close(fig)
    keys = [p["key"] for f in record["space"] for p in record["space"][f]]
    keys = list(dict.fromkeys(keys))
    fig, ax = plt.subplots(figsize=(7, 0.35 * len(keys) + 1.5))
    n = len(record["best"])
    for i, (f, b) in enumerate(record["best"].items()):
        imp = b.get("importance", {})
        ax.barh(np.arange(len(keys)) + i / (n + 1), [imp.get(k, 0.0) for k in keys], height=1 / (n + 1), label=f)
    ax.set_yticks(np.arange(len(keys)) + (n - 1) / (2 * (n + 1)))
    ax.set_yticklabels(keys)
    ax.set_xlabel("importance (fANOVA share of the score's variance)")
    ax.legend()
    save_figure(fig, fig_dir / "importance.png")
    plt.close(fig)
    return ["convergence.png", "importance.png"]


def cross_section(record: dict) -> list[str]:
    """"Each filter with the others' values": its training score with every other filter's searched
    values (docs/tuning.md), and a line per filter whose search stopped short (another's values
    score better than its own best by more than 2 %). Empty without the cross-check."""
    best = record["best"]
    if not any("cross" in b for b in best.values()):
        return []
    names = list(best)
    rows = []
    for f, b in best.items():
        cross = b.get("cross", {})
        rows.append([f, fmt(b["score"])] + ["—" if g == f or g not in cross else
                                             f"{fmt(cross[g]['score'])} ({-100 * cross[g]['gain']:+.0f} %)"
                                             for g in names])
    short = [f"- **{f}**: {g}'s searched values score {fmt(c['score'])} on its training runs, {100 * c['gain']:.0f} % "
             f"below its own best {fmt(best[f]['score'])}: its search stopped short of its optimum. Its rank among "
             "the tuned filters below reflects the search as much as the filter: run more trials (`--trials`) "
             "before reading it." for f, (g, c) in stopped_short(best).items()]
    lines = ["## Each filter with the others' values", "",
             "The training score of each filter (row) with every other filter's searched values on the parameters "
             "they share (its own on the rest, e.g. alpha), and the change against its own best (negative: "
             "better than its own); scored as its trials were, on the same training runs. A "
             "filter another's values serve better than its own best stopped short: an equal budget is not an "
             "equal search (docs/tuning.md).", "",
             md_table(["filter", "own best"] + [f"with {g}'s values" for g in names], rows), ""]
    return lines + (short + [""] if short else ["Every filter's own best is at least as good as the others' "
                                                  f"values (within {100 * FLAT:.0f} %).", ""])


def write_tune_report(out_dir: Path, n_boot: int = 2000) -> Path:
    """Write ``out_dir/report.md`` (and figures); return its path."""
    out_dir = Path(out_dir)
    record, trials = load(out_dir)
    on, test = record["tuned_on"], record["test"]
    lines = ["# Tuning report", "",
             f"Every filter searched with the same budget: {record['trials']} trials ({record['sampler']}), objective "
             f"`{record['objective']}`, on tracks {' '.join(map(str, on['tracks']))}, runs {on['runs'][0]}-"
             f"{on['runs'][1] - 1} of the training seed {on['seed']} (derived from --seed {on['seed_of']}). "
             "The tuned settings are in `tuned.toml` (docs/tuning.md).", ""]
    if test.get("overlap"):
        lines += [f"**Flagged:** the held-out tracks {' '.join(map(str, test['overlap']))} are also tuning tracks "
                  "(--allow-overlap): other realizations, the same trajectories; the held-out numbers are "
                  "optimistic.", ""]
    lines += ["## Training scores", "", score_table(record, trials), "",
              "## Tuned values beside the defaults", "",
              "A factor multiplies the study's std (the filter told the truth, or your options); a flat profile "
              "(the score moves < 2 % at x3 and /3, or ± a third of a linear range) marks a parameter this "
              "objective cannot see: its tuned "
              "value means nothing. *Searched* is the best trial's factor; *tuned* what `tuned.toml` writes "
              "(with the fitted level: every Q, R and P0 factor times the level's std factor).", "",
              values_table(record), ""]
    lines += cross_section(record)
    lt = level_table(record)
    if lt:
        lines += ["## The level", "",
                  "Scaling every variance of Q, R and P0 by one factor leaves an EKF's estimates unchanged and "
                  "divides its NEES by that factor; the search set the ratios for accuracy, the level was then "
                  "fitted so the geometric mean of the training tracks' ANEES is 6 (docs/tuning.md, \"The "
                  "level\"). The tuned values on the training runs, and each training track's ANEES: a held-out "
                  "track can land anywhere in that spread, so a wide spread says the filter's model misses "
                  "something the noise cannot cover (e.g. an unmodelled DVL lever arm).", "", lt, ""]
    d, t = out_dir / DEFAULT_DIR, out_dir / TUNED_DIR
    if (d / "metrics.parquet").exists() and (t / "metrics.parquet").exists():
        default, tuned = pd.read_parquet(d / "metrics.parquet"), pd.read_parquet(t / "metrics.parquet")
        words_d, words_t = heldout_consistency(d), heldout_consistency(t)
        where = f"tracks {' '.join(map(str, test['tracks']))}, {test['runs']} runs (seed {test['seed']})"
        lines += [f"## Held out: {where}", "",
                  "Default and tuned settings on the same realizations; improvement of the tuned over the default "
                  "velocity RMSE, paired by run, bootstrap 95 % interval; ANEES (6 dof) with its 95 % band.", "",
                  md_table(["filter", "VRMSE default", "ANEES default", "VRMSE tuned", "ANEES tuned",
                            "tuned vs default (+: tuned better)", "lost default", "lost tuned"],
                           heldout_rows(default, tuned, n_boot)),
                  "", "Consistency per state block and sensor on the held-out runs (the mc report's rule: the share "
                  "of epochs inside the 95 % bounds; the mean ANEES above only places the average):", "",
                  md_table(["filter", "default", "tuned"],
                           [[f, words_d.get(f, "—"), words_t.get(f, "—")] for f in dict.fromkeys(default["filter"])]),
                  "", "### The tuned filters compared", "",
                  md_table(["filter (tuned)", "VRMSE", "improvement of the best over it"], fair_rows(tuned, n_boot)),
                  ""]
    else:
        lines += ["## Held out", "", "No held-out runs (rerun with `--test-tracks`).", ""]
    names = figures(record, trials, out_dir / "figures")
    lines += ["## Figures", ""] + [f"![{n}](figures/{n})" for n in names] + [""]
    path = out_dir / "report.md"
    write_text_atomic(path, "\n".join(lines))
    return path


__all__ = ["is_tune_folder", "training_caveats", "write_tune_report"]
