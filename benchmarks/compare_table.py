"""The markdown of ``bench_compare.py``: medians, spreads, the two tables and the README section.

Pure functions of the measured numbers (standard library only; tests/test_bench_compare.py).
Units: costs per run-step [µs], CPU and wall times [s], memory [MB]; a ratio is now / base
(below 1: now is cheaper), each the median of the rounds' paired ratios.
"""
from __future__ import annotations

import statistics

BEGIN = "<!-- bench_compare:begin -->"
END = "<!-- bench_compare:end -->"
DASH = "—"
#: the issue's per run-step ceiling for ukf-nespm and ckf-nespm at R = 100 [µs]
POINT_FILTER_LIMIT_US = 1.5
POINT_FILTERS = ("ukf-nespm", "ckf-nespm")
#: now / base above this counts as slower (the rounds' spread is a few per cent)
SLOWER = 1.05
EKF_15_OVER_12_LIMIT = 1.3
TUNE_LIMIT = 1.5
MEMORY_LIMIT = 1.2


def median(values) -> float | None:
    """Median of the non-None ``values``; None when there are none."""
    vals = [v for v in values if v is not None]
    return statistics.median(vals) if vals else None


def spread(values) -> float | None:
    """``(max - min) / median`` of the non-None ``values`` (0 for one value); None when there are none."""
    vals = [v for v in values if v is not None]
    if not vals:
        return None
    m = statistics.median(vals)
    return (max(vals) - min(vals)) / m if m else 0.0


def paired_ratio(now, base) -> float | None:
    """Median over rounds of ``now[i] / base[i]`` (rounds where either is None or base is 0 skipped)."""
    return median([n / b for n, b in zip(now, base) if n is not None and b])


def fmt(value, digits: int = 2, suffix: str = "") -> str:
    """``value`` with ``digits`` decimals and ``suffix``, or the dash for None."""
    return DASH if value is None else f"{value:.{digits}f}{suffix}"


def step_series(rounds: list[dict], name: str, layout: str) -> list:
    """The cost [µs] of filter ``name`` in ``layout`` per round (None where the tree lacks it)."""
    return [r.get("cost_us", {}).get(name, {}).get(layout) for r in rounds]


def filter_rows(base: list[dict], now: list[dict]) -> list[str]:
    """The filters to show: now's built-ins in their order, then any only the base has."""
    names: list[str] = []
    for rounds in (now, base):
        for r in rounds:
            names += [n for n in r.get("filters", []) if n not in names]
    return names


def steps_table(base: list[dict], now: list[dict]) -> tuple[str, list[str]]:
    """(markdown table filter x [base, now, ratio] for the 12- and 15-state layouts, verdict lines)."""
    lines = ["| filter | 12, DVL: base [µs] | now [µs] | now/base | 15, DVL+depth+fixes: base [µs] | now [µs] | now/base |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    verdicts = []
    for name in filter_rows(base, now):
        cells = []
        for layout in ("12", "15"):
            b, n = step_series(base, name, layout), step_series(now, name, layout)
            ratio = paired_ratio(n, b)
            cells += [fmt(median(b), 3), fmt(median(n), 3), fmt(ratio, 2)]
            if name in POINT_FILTERS and layout == "12" and median(n) is not None:
                ok = median(n) <= POINT_FILTER_LIMIT_US
                verdicts.append(f"{name}, 12 states, R = 100: {median(n):.3f} µs "
                                f"(≤ {POINT_FILTER_LIMIT_US} µs: {'met' if ok else 'missed'})")
            elif name not in POINT_FILTERS and ratio is not None and ratio > SLOWER:
                verdicts.append(f"{name}, {layout} states: now/base {ratio:.2f} (slower than the base by more "
                                f"than {100 * (SLOWER - 1):.0f} %)")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    for label, rounds in (("base", base), ("now", now)):
        r = ekf_15_over_12(rounds)
        if r is not None:
            lines_note = f"EKF 15 states DVL+depth+fixes / 12 states DVL, {label}: {r:.2f}"
            if label == "now":
                lines_note += f" (≤ {EKF_15_OVER_12_LIMIT}: {'met' if r <= EKF_15_OVER_12_LIMIT else 'missed'})"
            verdicts.append(lines_note)
    return "\n".join(lines), verdicts


def ekf_15_over_12(rounds: list[dict]) -> float | None:
    """Median over rounds of the EKF's 15-state cost over its 12-state cost (same process, paired)."""
    return paired_ratio(step_series(rounds, "ekf", "15"), step_series(rounds, "ekf", "12"))


def jobs_table(res: dict) -> tuple[str, list[str]]:
    """(markdown table of the tuning overhead, the main job and the memory, verdict lines).

    ``res`` holds ``tune`` ({"trials", "runs", "mc_runs", "base"/"now": {"tune": [...], "mc": [...]} or
    None}), ``main`` ({"base"/"now": [{"wall_s", "cpu_s", "maxrss_mb", "tree_mb"}]}) and ``memory``
    ({"runs": [small, large], "now": {str(runs): [{"maxrss_mb", ...}]}})."""
    lines = ["| measure | base | now | now/base |", "| --- | ---: | ---: | ---: |"]
    verdicts = []
    tune = res.get("tune")
    if tune:
        over = {}
        for who in ("base", "now"):
            t = tune.get(who)
            if t:
                tc = [x["cpu_s"] for x in t["tune"]]
                mc = [x["cpu_s"] for x in t["mc"]]
                over[who] = (paired_ratio(tc, mc), median(tc), median(mc))
        label = f"`tune` {tune['trials']} trials x {tune['runs']} runs / `mc` {tune['mc_runs']} runs (ekf, CPU)"
        cell = {w: DASH if w not in over else f"{over[w][0]:.2f} ({over[w][1]:.1f} s / {over[w][2]:.1f} s)"
                for w in ("base", "now")}
        lines.append(f"| {label} | {cell['base']} | {cell['now']} | |")
        if "now" in over:
            r = over["now"][0]
            verdicts.append(f"tuning overhead: {r:.2f} x one {tune['mc_runs']}-run mc (≤ {TUNE_LIMIT}: "
                            f"{'met' if r <= TUNE_LIMIT else 'missed'})")
    main = res.get("main")
    if main:
        for key, label, digits in (("wall_s", "main job wall [s]", 1), ("cpu_s", "main job CPU, all processes [s]", 1),
                                   ("maxrss_mb", "main job peak RSS, largest process [MB]", 0),
                                   ("tree_mb", "main job peak RSS, all processes together [MB]", 0)):
            b = [x.get(key) for x in main.get("base") or []]
            n = [x.get(key) for x in main.get("now") or []]
            lines.append(f"| {label} | {fmt(median(b), digits)} | {fmt(median(n), digits)} | {fmt(paired_ratio(n, b))} |")
    mem = res.get("memory")
    if mem:
        small, large = mem["runs"]
        peaks = {}
        for runs in (small, large):
            for who in ("base", "now"):
                peaks[(who, runs)] = median([x["maxrss_mb"] for x in (mem.get(who) or {}).get(str(runs), [])])
            lines.append(f"| `mc` ekf, one track, {runs:,} runs, jobs 1: peak RSS [MB] | {fmt(peaks[('base', runs)], 0)} | "
                         f"{fmt(peaks[('now', runs)], 0)} | |")
        ratio = {w: (peaks[(w, large)] / peaks[(w, small)] if peaks[(w, large)] and peaks[(w, small)] else None)
                 for w in ("base", "now")}
        lines.append(f"| peak RSS {large:,} / {small:,} runs | {fmt(ratio['base'])} | {fmt(ratio['now'])} | |")
        if ratio["now"] is not None:
            verdicts.append(f"memory {large:,} / {small:,} runs: {ratio['now']:.2f} (≤ {MEMORY_LIMIT}: "
                            f"{'met' if ratio['now'] <= MEMORY_LIMIT else 'missed'})")
    return "\n".join(lines), verdicts


def spread_note(base: list[dict], now: list[dict]) -> str:
    """One sentence: how many rounds, and the spread of the per run-step costs over them."""
    spreads = []
    for rounds in (base, now):
        for name in filter_rows(base, now):
            for layout in ("12", "15"):
                s = spread(step_series(rounds, name, layout))
                if s is not None:
                    spreads.append((s, name, layout))
    if not spreads:
        return "No per run-step costs were measured."
    worst = max(spreads)
    return (f"{len(now)} round(s) per tree; spread of a cost over the rounds, (max - min) / median: median "
            f"{100 * median([s for s, *_ in spreads]):.1f} %, largest {100 * worst[0]:.1f} % ({worst[1]}, {worst[2]} states).")


def report(res: dict) -> str:
    """The whole markdown block: header lines, both tables, the must-hold verdicts."""
    steps_md, v1 = steps_table(res["steps"]["base"], res["steps"]["now"])
    jobs_md, v2 = jobs_table(res)
    head = [f"Base `{res['base']}` ({res.get('base_subject', '')}) against now `{res['now']}`; measured "
            f"{res.get('date', '?')} on {res.get('cpu', '?')}; {res.get('versions', '')}.",
            f"Per run-step: R = {res.get('runs', 100)} runs batched, {res.get('epochs_note', '')}, one core, CPU time "
            f"of the measuring process, one untimed warm-up run first, then the least of {res.get('repeat', 1)} timed run(s) "
            "per round; the trees measured in turn (base, now, base, now ...), "
            "each cell the median over the rounds, each ratio the median of the rounds' paired ratios.",
            spread_note(res["steps"]["base"], res["steps"]["now"])]
    if res.get("load"):
        head.append(f"Load average (1 min) at the start and the end: {res['load']}.")
    body = ["\n\n".join(head), steps_md, jobs_md, "Must-holds (issue 33):\n\n" + "\n".join(f"* {v}" for v in v1 + v2)]
    if res.get("notes"):
        body.append("\n".join(res["notes"]))
    return "\n\n".join(body) + "\n"


def rewrite_section(text: str, body: str) -> str:
    """``text`` with everything between :data:`BEGIN` and :data:`END` replaced by ``body``; the
    markers and a blank line around ``body`` are kept. Without the markers the section is appended
    (under a heading). ValueError if only one marker is present or they are out of order."""
    i, j = text.find(BEGIN), text.find(END)
    block = f"{BEGIN}\n\n{body.strip()}\n\n{END}"
    if i < 0 and j < 0:
        return text.rstrip("\n") + "\n\n## Now against a base commit (`bench_compare.py`)\n\n" + block + "\n"
    if i < 0 or j < 0 or j < i:
        raise ValueError(f"the README has a broken {BEGIN} ... {END} section")
    return text[:i] + block + text[j + len(END):]
