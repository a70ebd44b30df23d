"""The report of a ``nespm tune`` folder: ``OUT/report.md`` and ``OUT/figures/`` (docs/tuning.md).

Sections: what was tuned on (and whether the held-out tracks overlap it); per filter the default
and tuned training score and whether its search converged (:mod:`nespm_cli.reports.tune.searches`);
the tuned values beside the defaults with their range, importance and profile (a flat profile: the
objective cannot see the parameter); on the held-out runs (naming their time window), per filter the
default against the tuned settings by the mc report's rules (the epochs after t = 0), the consistency in
its one wording, where a model parameter may explain an inconsistency, the tuned filters against each
other and with ``--repeats K`` the searches (:mod:`nespm_cli.reports.tune.heldout`); figures: convergence (best
score so far against trial) and parameter importance. The setup counts each filter's training trials per
phase (search, refinement, checks) and the level's and held-out runs, so the cost beyond the search shows.
Without a ground truth (``tune.json``'s ``ground_truth`` false: ``--objective innovation`` on a track spec
without ``[gt]``) the training scores are the innovation statistics and the held-out part is
:func:`nespm_cli.reports.innovation.heldout_innovation_section`, and the report says so.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from nespm_cli.data.atomic import write_text_atomic
from nespm_cli.errors import NespmError
from nespm_cli.tuning.heldout import DEFAULT_DIR, TUNED_DIR
from nespm_cli.tuning.objective import beyond_limits
from nespm_cli.tuning.profile import FLAT, stopped_short
from nespm_cli.filters.options import TUNED_ON, training_overlap
from nespm_cli.reports.figures import save_figure, use_agg
from nespm_cli.reports.innovation import heldout_innovation_section
from nespm_cli.reports.markdown import fmt, md_table
from nespm_cli.reports.tune.heldout import heldout_section, window_text
from nespm_cli.reports.tune.searches import convergence_of, convergence_text


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
            written = fmt(b["values"][k])
            if p["kind"] in ("Q", "R", "P0") and np.isfinite(shape):  # the level pushed it past a limit: said
                for raw in beyond_limits({k: shape}, {k: shape}, float(b.get("level", 1.0))).values():
                    written += f" (clipped: {fmt(raw)} at the level)"
            rows.append([f, k, p["kind"], fmt(p["default"]), fmt(shape), written,
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


def search_trials(trials: pd.DataFrame, search: int = 0) -> pd.DataFrame:
    """The rows of ``trials.parquet`` of search ``search`` (``--repeats``; every row of a folder without
    the ``search`` column)."""
    return trials[trials["search"] == search] if "search" in trials.columns else trials


def score_table(record: dict, trials: pd.DataFrame) -> str:
    """Per filter (its first search, ``tuned.toml``'s): the default and tuned training score, RMSE and
    consistency, the best trial, and the search's convergence verdict."""
    rows = []
    trials = search_trials(trials)
    truth = record.get("ground_truth", True)  # without one: the innovation NLL and the NIS's band distance
    a, b_, names = ("rmse", "consistency", ("RMSE", "consistency")) if truth else (
        "innovation_nll", "nis_distance", ("innovation NLL", "NIS distance from its band"))
    for f, b in record["best"].items():
        t = trials[trials["filter"] == f].set_index("trial")
        d = t.loc[b["default_trial"]] if b.get("default_trial") is not None else None
        best = t.loc[b["trial"]]
        rows.append([f, fmt(b.get("default_score")), fmt(b["score"]), str(b["trial"]),
                     fmt(d[a]) if d is not None else "—", fmt(best[a]),
                     fmt(d[b_]) if d is not None else "—", fmt(best[b_]),
                     convergence_text(convergence_of(b))])
    return md_table(["filter", "score default", "score tuned", "best trial", f"{names[0]} default",
                     f"{names[0]} tuned", f"{names[1]} default", f"{names[1]} tuned", "search"], rows)


def cost_lines(record: dict, trials: pd.DataFrame) -> list[str]:
    """The training cost per filter: its trials per phase (``trials.parquet``'s ``phase``: the global search,
    the refinement, the checks), each of ``runs x tracks`` filter-runs, the level's runs and the held-out runs
    (``tune.json``)."""
    on, test = record["tuned_on"], record["test"]
    each = (on["runs"][1] - on["runs"][0]) * len(on["tracks"])
    done = trials[trials["state"] == "COMPLETE"] if "state" in trials.columns else trials
    out = []
    for f, b in record["best"].items():
        mine = done[done["filter"] == f]
        counts = (mine["phase"].value_counts() if "phase" in mine.columns else pd.Series({"search": len(mine)}))
        parts = [f"{int(counts.get(p, 0))} {w}" for p, w in (("search", "search"), ("refine", "refine"),
                                                               ("check", "check"))]
        level = (f"; the level: {b['level_runs']} runs x {len(on['tracks'])} tracks" if "level_runs" in b else "")
        out.append(f"- **{f}**: trials: {' + '.join(parts)} = {len(mine)}, each {each} filter-runs "
                   f"({len(mine) * each} in all){level}")
    held = (f"; held out: {test['runs']} runs x tracks {' '.join(map(str, test['tracks']))}, default and tuned"
            if test.get("tracks") else "")
    return [f"Training cost (runs {on['runs'][0]}-{on['runs'][1] - 1} x tracks {' '.join(map(str, on['tracks']))} "
            f"per trial{held}):", ""] + out + [""]


def figures(record: dict, trials: pd.DataFrame, fig_dir: Path) -> list[str]:
    """convergence.png (best score so far against trial; with ``--repeats`` the other searches dotted) and
    importance.png (none where no importance was computed: ``--no-profile``); their file names."""
    use_agg()
    import matplotlib.pyplot as plt

    fig_dir.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(7, 4))
    done = trials[trials["state"] == "COMPLETE"]
    if "phase" in done.columns:  # the profile's and cross-check's trials are no step of the search
        done = done[done["phase"] != "check"]
    searches = sorted(set(done["search"])) if "search" in done.columns else [0]
    for i, f in enumerate(record["best"]):
        for k in searches:
            t = search_trials(done, k)
            t = t[t["filter"] == f].sort_values("trial")
            ax.step(t["trial"], np.minimum.accumulate(t["score"].to_numpy()), where="post", color=f"C{i}",
                    label=f if k == 0 else None, lw=1.5 if k == 0 else 0.8, ls="-" if k == 0 else ":")
    ax.set_yscale("log")
    ax.set_xlabel("trial")
    ax.set_ylabel(f"best score so far ({record['objective']})")
    ax.legend()
    save_figure(fig, fig_dir / "convergence.png")
    plt.close(fig)
    if not any(b.get("importance") for b in record["best"].values()):  # --no-profile: no importance computed
        return ["convergence.png"]
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
    if not record.get("ground_truth", True):
        lines += ["**No ground truth: innovation statistics only.** The tracks have no truth file (a track spec "
                  "without [gt]): the filters were scored by their innovations alone, and no error or NEES is "
                  "shown (docs/tuning.md, \"Tuning without ground truth\").", ""]
    lines += cost_lines(record, trials)
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
              "(with the fitted level: every Q, R and P0 factor times the level's std factor, kept within the noise-scale "
              "limits 1e-3 to 1e3 that `--config` accepts: a clipped one says so).", "",
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
    if (d / "metrics.parquet").exists() and (t / "metrics.parquet").exists() and not record.get("ground_truth", True):
        where = (f"tracks {' '.join(map(str, test['tracks']))}, {test['runs']} runs (seed {test['seed']}), "
                 f"{window_text(record)}")
        lines += heldout_innovation_section(out_dir, record, DEFAULT_DIR, TUNED_DIR, where, n_boot)
    elif (d / "metrics.parquet").exists() and (t / "metrics.parquet").exists():
        lines += heldout_section(out_dir, record, n_boot)
    else:
        lines += ["## Held out", "", "No held-out runs (rerun with `--test-tracks`).", ""]
    names = figures(record, trials, out_dir / "figures")
    lines += ["## Figures", ""] + [f"![{n}](figures/{n})" for n in names] + [""]
    path = out_dir / "report.md"
    write_text_atomic(path, "\n".join(lines))
    return path


__all__ = ["is_tune_folder", "training_caveats", "write_tune_report"]
