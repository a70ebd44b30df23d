"""The report of a ``nespm tune`` folder: ``OUT/report.md`` and ``OUT/figures/`` (docs/tuning.md).

Sections: what was tuned on (and whether the held-out tracks overlap it); per filter the default
and tuned training score and whether its search converged (:mod:`nespm_cli.reports.tune_searches`);
the tuned values beside the defaults with their range, importance and profile (a flat profile: the
objective cannot see the parameter); on the held-out runs (naming their time window), per filter the
default against the tuned settings on the objective's error (the horizontal RMS error with position
in the state, else the VRMSE; the VRMSE beside) by the mc report's rule (the epochs after t = 0, eq 50
per track, eq 51 over tracks; paired bootstrap 95 % interval of the improvement), the ANEES against
its band and the consistency per block, a line per tuned filter left inconsistent on where a model
parameter (a lever arm) may explain it, the tuned filters against each other (the fair comparison),
and with ``--repeats K`` the searches compared over runs and searches; figures: convergence (best
score so far against trial) and parameter importance. The setup counts each filter's training trials per
phase (search, refinement, checks) and the level's and held-out runs, so the cost beyond the search shows.
Without a ground truth (``tune.json``'s ``ground_truth`` false: ``--objective innovation`` on a track spec
without ``[gt]``) the training scores are the innovation statistics and the held-out part is
:func:`nespm_cli.reports.innovation.heldout_innovation_section`, and the report says so.
"""
from __future__ import annotations

import json
import math
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
from nespm_cli.reports.innovation import heldout_innovation_section
from nespm_cli.reports.markdown import fmt, fmt_imprv, md_table
from nespm_cli.reports.results import load_results
from nespm_cli.reports.stats import (ci_marks, improvement, nees_check, paired_averages, paired_bootstrap,
                                     paired_improvement, paired_run_counts, percentile_ci, posterior_view)
from nespm_cli.reports.tune_searches import (ACCURACY, accuracy_key, consistency_scores, convergence_of,
                                             convergence_text, filter_values, searches_section)


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


def heldout_rows(default: pd.DataFrame, tuned: pd.DataFrame, keys: list[str], n_boot: int) -> list[dict]:
    """Per filter: default against tuned on the same held-out runs, by the mc report's rule for each error
    ``key`` of ``keys`` (``vrmse``, ``hpe``): the posterior sums (t = 0 out, :func:`stats.posterior_view`),
    eq 50 per track over the runs neither lost, eq 51 over tracks; ``{key: (default, tuned, improvement of
    tuned [%], lo, hi, mark)}`` (paired bootstrap 95 % interval, ``†`` under 10 pairs on a track), and
    ``nees`` ({"default", "tuned"}: the mean per-run NEES over the runs each kept), ``lost``, ``posterior``
    (False: a folder without the posterior sums, every epoch counted)."""
    rows = []
    for f in sorted(set(default["filter"]) & set(tuned["filter"]), key=list(default["filter"].unique()).index):
        a, b = f"{f} default", f"{f} tuned"
        m = posterior_view(pd.concat([default[default["filter"] == f].assign(filter=a),
                                      tuned[tuned["filter"] == f].assign(filter=b)], ignore_index=True))
        row = {"filter": f, "posterior": bool(m.attrs["posterior"]), "nees": {}, "lost": {}}
        averages = paired_averages(m, a, b, keys)
        boot = paired_bootstrap(m, a, b, n_boot=n_boot, keys=keys)
        counts = paired_run_counts(m, a, b)
        for k in keys:
            lo, hi = percentile_ci(boot[k])
            row[k] = (*averages[k], float(improvement(*averages[k])), lo, hi,
                      ci_marks(lo, hi, min(counts.values()) if counts else 0)[2])
        for side, part in (("default", default), ("tuned", tuned)):
            mine = part[part["filter"] == f]
            row["nees"][side] = (float(mine.loc[~mine["diverged"], "nees"].mean()), int((~mine["diverged"]).sum()))
            row["lost"][side] = int(mine["diverged"].sum())
        rows.append(row)
    return rows


def heldout_table(rows: list[dict], keys: list[str], scores: tuple[dict, dict] | None) -> str:
    """Markdown of :func:`heldout_rows`; ``scores`` (default, tuned) ``{filter: consistency score}`` adds
    the consistency objective's own score beside."""
    head = ["filter"]
    for k in keys:
        name = ACCURACY[k][0]
        head += [f"{name} default", f"{name} tuned", f"{name}: tuned vs default (+: tuned better)"]
    head += (["consistency score default", "consistency score tuned"] if scores else []) + [
        "ANEES default", "ANEES tuned", "lost default", "lost tuned"]
    out = []
    for r in rows:
        cells = [r["filter"]]
        for k in keys:
            d, t, point, lo, hi, mark = r[k]
            cells += [fmt(d), fmt(t), fmt_imprv(point, lo, hi, mark)]
        if scores:
            cells += [fmt(scores[0].get(r["filter"], math.nan)), fmt(scores[1].get(r["filter"], math.nan))]
        for side in ("default", "tuned"):
            nees, n = r["nees"][side]
            lo, hi, word = nees_check(nees, n)
            cells.append(f"{fmt(nees, '.3g')} [{fmt(lo, '.3g')}, {fmt(hi, '.3g')}] {word}")
        out.append(cells + [str(r["lost"]["default"]), str(r["lost"]["tuned"])])
    return md_table(head, out)


def heldout_consistency(epochs: pd.DataFrame | None, manifest: dict) -> dict:
    """Per filter of a held-out mc folder (its ``epochs.parquet`` and manifest): the per-block consistency
    words (the mc report's rule: the share of epochs inside the 95 % bounds, docs/report.md
    "Consistency"); {} without per-epoch columns."""
    return {} if epochs is None else consistency_words(block_consistency(epochs, manifest))


def fair_rows(tuned: pd.DataFrame, key: str, n_boot: int) -> list[list[str]]:
    """The tuned filters against the most accurate tuned one on error ``key`` (:func:`filter_values`:
    t = 0 out, over the runs no filter lost; improvements paired over the runs each pair kept)."""
    values = filter_values(tuned, key)
    m = posterior_view(tuned)
    best = min(values, key=values.get)
    rows = []
    for f in sorted(values, key=values.get):
        if f == best:
            rows.append([f, fmt(values[f]), "(reference)"])
            continue
        point = paired_improvement(m, f, best, keys=[key])[key]
        lo, hi = percentile_ci(paired_bootstrap(m, f, best, n_boot=n_boot, keys=[key])[key])
        counts = paired_run_counts(m, f, best)
        rows.append([f, fmt(values[f]), fmt_imprv(point, lo, hi, ci_marks(lo, hi, min(counts.values()))[2])])
    return rows


def sensor_cells(manifest: dict) -> dict[str, dict]:
    """``{sensor: its recorded options}`` of an mc folder's manifest (the first cell holding each)."""
    out: dict[str, dict] = {}
    for cell in (manifest.get("sensors") or {}).values():
        for name, o in (cell.items() if isinstance(cell, dict) else ()):
            if isinstance(o, dict):
                out.setdefault(name, o)
    return out


def model_note(f: str, record: dict, sensors: dict[str, dict]) -> str:
    """Where a model parameter may explain filter ``f``'s tuned held-out inconsistency: per sensor whose
    model reads a lever arm, the lever arm of ``f``'s model (searched, or fixed while the sensor's
    measurements are recorded: a wrong one adds ``ω × l`` in every turn, which no Q, R or P0 covers on
    every track); with every lever arm searched or synthetic, the model parameters ``f`` does not hold;
    and the spread of its training tracks' ANEES at the fitted level."""
    from nespm_cli.filters.options import AXES, lever_key
    from nespm_cli.sensors.registry import get_sensor

    b = record["best"][f]
    searched = {p["key"] for p in record["space"].get(f, []) if p.get("kind") == "model"}
    given = {o[1]: o[2] for o in (record.get("spec") or {}).get("filter_options", []) if o[0] == f}
    parts, open_lever = [], False
    for s, o in sensors.items():
        try:
            if "lever_arm" not in o or not get_sensor(s).has_lever:
                continue
        except NespmError:  # a plugin sensor not loaded here: its model is unknown
            continue
        keys = [lever_key(s, a) for a in AXES]
        arm = [float(b["values"].get(k, given.get(k, v))) for k, v in zip(keys, o["lever_arm"])]
        where = "(" + ", ".join(f"{v:.3g}" for v in arm) + ") m"
        done = [k for k in keys if k in searched]
        if done:
            parts.append(f"its {s} lever arm was searched ({', '.join(done)}): {where}")
        if o.get("source") == "recorded" and len(done) < len(keys):
            open_lever = True
            parts.append(f"its model puts the {s} at {where} from the IMU{' (the other axes fixed)' if done else ''} "
                         f"while the {s} measurements are recorded: a lever arm the model gets wrong adds `ω × l` in "
                         "every turn, an error no Q, R or P0 covers on every track (the embedded and Snapir DVLs sit "
                         f"1.6-2.1 m aft); search it (`--tune-range '*.{lever_key(s, 'x')}=-3:3'`) or give it "
                         f"(`--filter-option {f}.{lever_key(s, 'x')}=...`)")
    recorded = (record.get("spec") or {}).get("imu") == "recorded" or any(
        o.get("source") == "recorded" for o in sensors.values())
    if recorded and not open_lever:
        parts.append("what is left may be a model parameter the filter does not hold (a sensor's time offset, scale "
                     "factor or misalignment: `nespm check` fits them) or held-out tracks unlike the training ones")
    elif not recorded:
        parts.append("its IMU and sensors are synthetic, drawn with its model's lever arms: not a model parameter but "
                     f"the noise's shape or level (the level fitted on {b.get('level_runs', '—')} runs per track "
                     "carries their sampling spread) or held-out tracks unlike the training ones")
    spread = [float(v) for v in (b.get("at_level_tracks") or {}).values() if np.isfinite(v)]
    if len(spread) > 1:
        parts.append(f"its training tracks' ANEES at the level spread from {min(spread):.3g} to {max(spread):.3g} "
                     "(a wide spread: the model misses something the noise cannot cover)")
    text = "; ".join(parts)
    return text[:1].upper() + text[1:]


def model_lines(rows: list[dict], words: dict, record: dict, sensors: dict[str, dict]) -> list[str]:
    """A line per filter whose tuned settings are not consistent on the held-out runs (its mean ANEES
    outside its band, or a block or sensor by the share rule), with :func:`model_note`."""
    lines = []
    for r in rows:
        f = r["filter"]
        word = nees_check(*r["nees"]["tuned"])[2]
        blocks = words.get(f, "consistent")
        if word in ("consistent", "—") and blocks in ("consistent", "—"):
            continue
        lines.append(f"- **{f}** tuned: ANEES {word}, blocks {blocks}. {model_note(f, record, sensors)}.")
    if not lines:
        return []
    return ["Where a model parameter may explain it (docs/tuning.md, \"When tuning cannot make a filter "
            "consistent\"):", ""] + lines + [""]


def figures(record: dict, trials: pd.DataFrame, fig_dir: Path) -> list[str]:
    """convergence.png (best score so far against trial; with ``--repeats`` the other searches dotted) and
    importance.png; their file names."""
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


def window_text(record: dict) -> str:
    """The time window the runs used: ``window 0:60 s of each track's GT time`` or ``whole tracks``."""
    w = (record.get("spec") or {}).get("window")
    return f"window {w} s of each track's GT time (`--window`)" if w else "whole tracks"


def heldout_section(out_dir: Path, record: dict, n_boot: int) -> list[str]:
    """"Held out": per filter the default against the tuned settings on the objective's error (and the
    VRMSE beside it), the consistency per block, where a model parameter may explain an inconsistency,
    the tuned filters compared and (``--repeats``) the searches."""
    test = record["test"]
    (default, ep_d, man_d), (tuned, ep_t, manifest) = (load_results(out_dir / DEFAULT_DIR),
                                                       load_results(out_dir / TUNED_DIR))
    key = accuracy_key(record)
    keys = list(dict.fromkeys([key, "vrmse"]))
    rows = heldout_rows(default, tuned, keys, n_boot)
    scores = None
    if record.get("objective") == "consistency":
        scores = (consistency_scores(ep_d, man_d), consistency_scores(ep_t, manifest))
    words_d, words_t = heldout_consistency(ep_d, man_d), heldout_consistency(ep_t, manifest)
    epochs = ("the epochs after t = 0 (posterior sums; the mc report's verdict and comparisons, docs/report.md "
              "\"The t = 0 rule\")" if all(r["posterior"] for r in rows) else
              "every epoch including t = 0 (a folder written before the posterior sums: the improvements are "
              "diluted towards 0; rerun `nespm tune` into a new folder)")
    name = ACCURACY[key][0]
    own = ("The consistency score is the objective's own (the mean over blocks and sensors of log(ANEES/3)² and "
           "log(ANIS/m)² over the epochs after t = 0, from the per-epoch averages; no interval). "
           if scores else "")
    scored = record.get("objective") in ("rmse", "rmse-consistent")
    what = (f"The {name} ({'the error the objective scores' if scored else 'not scored by this objective'})"
            + ("" if key == "vrmse" else " and the VRMSE beside it"))
    where = (f"tracks {' '.join(map(str, test['tracks']))}, {test['runs']} runs (seed {test['seed']}), "
             f"{window_text(record)}")
    lines = [f"## Held out: {where}", "",
             f"Default and tuned settings on the same realizations. {own}{what}: over {epochs}, eq 50 per track "
             "over the runs neither setting lost, eq 51 over tracks; the improvement of the tuned over the default "
             "paired by run with its bootstrap 95 % interval (`†`: fewer than 10 paired runs on a track, too few "
             "for the interval); ANEES (6 dof, the mean per-run NEES over all epochs, as the mc report's) with its "
             "95 % band.", "", heldout_table(rows, keys, scores), "",
             "Consistency per state block and sensor on the held-out runs (the mc report's rule: the share "
             "of epochs inside the 95 % bounds; the mean ANEES above only places the average):", "",
             md_table(["filter", "default", "tuned"],
                      [[f, words_d.get(f, "—"), words_t.get(f, "—")] for f in dict.fromkeys(default["filter"])]),
             ""]
    lines += model_lines(rows, words_t, record, sensor_cells(manifest))
    many = int(record.get("repeats", 1) or 1) > 1 and record.get("searches")
    lines += ["### The tuned filters compared", "",
              f"Each tuned filter (search 0: `tuned.toml`) against the most accurate one on the {name}, by the same "
              "rule (the runs no filter lost; improvements paired by run). " +
              ("The intervals cover the runs only: the searches below say how much a search's luck moves it."
               if many else "One search per filter: the intervals cover the runs, not the search's luck "
               "(`nespm tune --repeats K` runs K searches and compares over both)."), "",
              md_table(["filter (tuned)", name, "improvement of the best over it"], fair_rows(tuned, key, n_boot)),
              ""]
    return lines + searches_section(out_dir, record, n_boot)


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
