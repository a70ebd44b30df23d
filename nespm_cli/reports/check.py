"""The report of ``nespm check``: check.md, check.json, corrections.json and figures."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from nespm_cli.data.atomic import write_text_atomic
from nespm_cli.reports.figures import save_figure, use_agg
from nespm_cli.reports.markdown import fmt, md_table

DEG_H = 180.0 / math.pi * 3600.0  # rad/s -> deg/h


def verdict_text(r: dict) -> str:
    """The verdict with its reasons, short (``inconsistent (DVL looks like NED velocity; DVL residual 1.19 m/s)``)."""
    reasons = r.get("verdict_reasons") or []
    return f"{r['verdict']} ({'; '.join(reasons)})" if reasons else r["verdict"]


def frame_text(d: dict) -> str:
    """The DVL's own noise, the bound and the frame test of :func:`checks.dvl_verdict.judge_dvl`, one sentence."""
    j = d.get("judged")
    if not j:
        return ""
    f = j["frame"]
    cand = ", ".join(f"{name} {fmt(f[k]['rms'], '.3f')}" for k, name in
                     (("body", "as body"), ("ned", "as NED"), ("enu", "as ENU"))) + \
        f", best other body axes ({f['axes']['axes'] or '-'}) {fmt(f['axes']['rms'], '.3f')}"
    return (f"DVL's own noise {fmt(j['noise'], '.4f')} m/s (from its second difference), bound {fmt(j['bound'], '.3f')} "
            f"m/s, RMS speed {fmt(j['speed_rms'], '.2f')} m/s; frame test, RMS residual at each reading's best "
            f"offset: {cand} m/s.")


def summary_rows(result: dict) -> list[list[str]]:
    """One row per track: verdict, IMU axes, IMU offset, worst gyro correlation, attitude drift,
    DVL offset, lever arm, scale factor, misalignment, DVL residual, and the options."""
    rows = []
    for r in result["tracks"]:
        imu, dvl = r["imu"], r["dvl"]
        if imu is None:
            imu_cells = ["no IMU file", "—", "—", "—"]
        else:
            o = imu["time_offset"]
            imu_cells = [imu["axis_mapping"]["axes"], f"{o['offset_s']:+.2f} ± {o['std_s']:.2f}",
                         fmt(min(imu["stats"]["gyro"]["corr"]), ".3f"),
                         ", ".join(f"{a:+.1f}" for a in imu["attitude_drift"]["final_deg"])]
        sf = dvl["scale_factor"]
        mis = dvl["misalignment_deg"]
        rows.append([
            str(r["track"]), verdict_text(r), *imu_cells,
            f"{dvl['time_offset_s']:+.2f} ± {fmt(dvl['time_offset_std_s'], '.2f')}",
            "(" + ", ".join(f"{x:.2f}" for x in dvl["lever_arm"]) + ")",
            f"{100 * sf:+.2f}", "(" + ", ".join(f"{x:+.2f}" for x in mis) + ")",
            f"{dvl['resid_rms_after']:.3f}", f"`{r['options']}`" if r["options"] else "none",
        ])
    return rows


HEADERS = ["track", "verdict", "IMU axes", "IMU offset [s]", "min gyro corr", "gyro attitude drift [deg, NED]",
           "DVL offset [s]", "lever arm [m]", "DVL scale [%]", "DVL misalign. [deg]", "DVL resid [m/s]",
           "options"]


def summary_table(result: dict) -> str:
    """The table ``nespm check`` prints (markdown)."""
    return md_table(HEADERS, summary_rows(result))


def track_section(r: dict, fig_names: list[str]) -> str:
    lines = [f"## Track {r['track']}: {r['verdict']}", "", f"Source: `{r['source']}`", ""]
    if r.get("verdict_reasons"):
        lines += [f"**Inconsistent:** {'; '.join(r['verdict_reasons'])} (the findings below say why and what to set).", ""]
    lines += [f"- {f}" for f in r["findings"]]
    lines.append("")
    if r["options"]:
        lines += [f"Options that apply the corrections: `{r['options']}`", ""]
    imu = r["imu"]
    if imu is not None:
        rows = []
        for key, unit, scale in (("gyro", "deg/h", DEG_H), ("acc", "mg", 1000 / 9.80665)):
            s = imu["stats"][key]
            for i, ax in enumerate("xyz"):
                rows.append([f"{key} {ax}", f"{s['corr'][i]:.3f}", f"{s['resid_mean'][i] * scale:+.3g}",
                             f"{s['resid_std'][i] * scale:.3g}", f"{s['signal_std'][i] * scale:.3g}",
                             f"{100 * s['scale_factor'][i]:+.2f}", unit])
        lines += ["IMU against the GT-implied IMU (both low-passed; after the axis mapping and time offset):", "",
                  md_table(["axis", "corr", "resid mean", "resid std", "signal std", "scale [%]", "unit"], rows), ""]
        for label in ("inconsistent", "unresolved"):
            bad = [w for w in imu["windows"] if w[label]]
            lines.append(f"Windows ({len(imu['windows'])} of 20 s every 10 s): {len(bad)} {label}"
                         + (": " + ", ".join(f"{w['start']:.0f}-{w['end']:.0f} s" for w in bad) if bad else "") + ".")
        lines.append("")
    d = r["dvl"]
    und = ", ".join(d.get("undetermined") or []) or "none"

    def vec(xs, spec: str) -> str:  # a value the check could not form (a DVL at its own stamps): a dash
        return fmt(None) if xs is None else ", ".join(fmt(x, spec) for x in xs)

    lines += [f"DVL against GT: time offset {fmt(d.get('time_offset_s'), '+.3f')} ± {fmt(d.get('time_offset_std_s'), '.3g')} s, "
              f"lever arm ({vec(d.get('lever_arm'), '.3f')}) ± ({vec(d.get('lever_arm_std'), '.3g')}) m, "
              f"scale factor {fmt(d.get('scale_factor'), '+.4f')} ± {fmt(d.get('scale_factor_std'), '.3g')}, misalignment "
              f"({vec(d.get('misalignment_deg'), '+.3f')}) ± ({vec(d.get('misalignment_std_deg'), '.3g')}) deg; residual std "
              f"({vec(d.get('resid_std_before'), '.3f')}) m/s after the lever arm alone, "
              f"({vec(d.get('resid_std_after'), '.3f')}) after all four. Undetermined: {und}.", ""]
    if d.get("judged"):
        lines += [frame_text(d), ""]
    lines += [f"![{n}]({n})" for n in fig_names]
    lines.append("")
    return "\n".join(lines)


def plot_track(r: dict, out: Path) -> list[str]:
    """Figures of one track: rates over time with the windows marked, residuals, offset curves."""
    use_agg()
    import matplotlib.pyplot as plt

    names = []
    imu = r["imu"]
    n = r["track"]
    if imu is not None:
        s = imu["series"]
        t = np.asarray(s["t"])
        fig, axes = plt.subplots(4, 1, figsize=(10, 9), sharex=True)
        for i, ax in enumerate("xyz"):
            a = axes[i]
            a.plot(t, np.degrees(np.asarray(s["implied_w"])[:, i]), lw=1, label="implied by GT")
            a.plot(t, np.degrees(np.asarray(s["recorded_w"])[:, i]), lw=1, alpha=0.8, label="recorded (corrected)")
            a.set_ylabel(f"gyro {ax} [deg/s]")
        resid = np.asarray(s["resid_w"]) * DEG_H
        for i, ax in enumerate("xyz"):
            axes[3].plot(t, resid[:, i], lw=0.8, label=f"{ax}")
        axes[3].set_ylabel("residual [deg/h]")
        axes[3].set_xlabel("t [s]")
        for w in imu["windows"]:
            if w["inconsistent"] or w["unresolved"]:
                for a in axes:
                    a.axvspan(w["start"], w["end"], color="red" if w["inconsistent"] else "grey", alpha=0.12, lw=0)
        axes[0].legend(loc="upper right", fontsize=8)
        axes[3].legend(loc="upper right", fontsize=8, ncol=3)
        axes[0].set_title(f"track {n}: recorded vs GT-implied angular rate (low-passed {0.3:g} Hz); red: inconsistent, grey: unresolved windows")
        names.append(save_figure(fig, out / f"check-track{n}-rates.png").name)
    fig, axes = plt.subplots(1, 3 if imu is not None else 1, figsize=(14 if imu is not None else 5, 3.5), squeeze=False)
    k = 0
    if imu is not None:
        o = imu["time_offset"]
        c = o["curve"]
        axes[0, 0].plot(c["offset_s"], c["cost"])
        axes[0, 0].axvline(o["offset_s"], color="k", ls=":")
        axes[0, 0].set_xlabel("IMU time offset at t = 0 [s]" + (" (drift applied)" if o["drift"]["drift"] else ""))
        axes[0, 0].set_ylabel("normalised gyro residual")
        axes[0, 0].set_yscale("log")
        loc = [w for w in o["local"] if not w["at_edge"] and math.isfinite(w["std_s"])]
        if loc:
            axes[0, 1].errorbar([w["t"] for w in loc], [w["offset_s"] for w in loc],
                                yerr=[w["std_s"] for w in loc], fmt="o", ms=3)
            d = o["drift"]
            if d.get("intercept_s") is not None:
                tt = np.array([loc[0]["t"], loc[-1]["t"]])
                axes[0, 1].plot(tt, d["intercept_s"] + d["drift_fit"] * tt, "k--",
                                label=f"drift {d['drift_fit'] * 1e6:+.0f} ppm")
                axes[0, 1].legend(fontsize=8)
        axes[0, 1].set_xlabel("t [s]")
        axes[0, 1].set_ylabel("local IMU offset (40 s windows) [s]")
        k = 2
    c = r["dvl"]["offset_curve"]
    axes[0, k].plot(c["tau_s"], c["rms"])
    axes[0, k].axvline(r["dvl"]["time_offset_s"], color="k", ls=":")
    axes[0, k].set_xlabel("DVL time offset [s]")
    axes[0, k].set_ylabel("DVL residual RMS [m/s]")
    fig.suptitle(f"track {n}: time-offset search")
    names.append(save_figure(fig, out / f"check-track{n}-offsets.png").name)
    return names


def strip_series(r: dict) -> dict:
    """The track's result without the plotted time series (check.json stays small)."""
    if r["imu"] is None:
        return r
    imu = {k: v for k, v in r["imu"].items() if k != "series"}
    imu["attitude_drift"] = {k: v for k, v in imu["attitude_drift"].items() if k not in ("t", "drift_deg")}
    return {**r, "imu": imu}


def write_check_report(result: dict, out: str | Path, figures: bool = True) -> Path:
    """Write ``out/check.md``, ``out/check.json``, ``out/corrections.json`` and the figures; return check.md."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    where = result["data_dir"] or "the embedded default tracks"
    verdicts = ", ".join(f"{v} {k}" for k, v in sorted(result["summary"].items()))
    parts = [f"# Data check of {where}", "", f"{len(result['tracks'])} tracks: {verdicts}.", "",
             summary_table(result), "",
             "Offsets are stamp minus GT time (subtract them from the stamps); drift is the attitude the "
             "recorded gyros integrate away from the GT; `options` apply the corrections the data justify "
             "(all of them: `--corrections corrections.json`). How each number is found: docs/checking-data.md.", ""]
    for r in result["tracks"]:
        names = plot_track(r, out) if figures else []
        parts.append(track_section(r, names))
    from nespm_cli.checks.verdict import json_safe  # a non-finite figure as null

    tracks = [strip_series(r) for r in result["tracks"]]
    write_text_atomic(out / "check.json", json.dumps(json_safe({**result, "tracks": tracks}), indent=1,
                                                     allow_nan=False) + "\n")
    write_text_atomic(out / "corrections.json", result["corrections"])
    path = out / "check.md"
    write_text_atomic(path, "\n".join(parts))
    return path
