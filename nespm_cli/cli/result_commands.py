"""The commands that read a results folder: ``nespm report`` and ``nespm export``."""
from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from nespm_cli.experiments.progress import Status
from nespm_cli.reports.thresholds import PRACTICAL_PCT


def non_empty_out(out: str) -> Path:
    """``--out`` as a path; an empty one (which would mean the current folder) is one line."""
    from nespm_cli.errors import NespmError

    if not out.strip():
        raise NespmError("--out: an empty path (it would write into the current folder); name a folder")
    return Path(out)


def report(
    out_dir: Path = typer.Argument(..., help="Folder written by 'nespm mc', 'nespm sweep' or 'nespm gp-ukf'."),
    baseline: Optional[str] = typer.Option(None, "--baseline", help="Filter whose improvement over each other row is shown (the papers' 'Imprv.' column) and the verdict's reference; not an RTS-smoother floor (<filter>-rts)."),
    n_boot: int = typer.Option(2000, "--n-boot", help="Paired bootstrap resamples for the 95 % intervals."),
    practical: float = typer.Option(PRACTICAL_PCT, "--practical", help="Smallest improvement [%] the verdict calls practically meaningful (a difference must also be statistically significant)."),
    all_runs: str = typer.Option("median", "--all-runs", help="Where runs were lost: 'median' adds the comparison over every run, a lost run ranked the worst (medians, paired median improvements, losses; docs/report.md); 'none' leaves it out."),
    consistent_share: Optional[float] = typer.Option(None, "--consistent-share", help="Least share of the epochs (0-1] whose ANEES / ANIS lies inside its 95 % bounds for a state block or sensor to be called consistent (default 0.8; docs/report.md, \"Consistency\"); mc folders."),
    beside: Optional[List[Path]] = typer.Option(None, "--beside", help="Another mc folder whose numbers are set beside this one's (e.g. the synthetic-IMU run of a recorded-IMU one); repeatable."),
    no_progress: bool = typer.Option(False, "--no-progress", help="Do not say what is being done (a status on a terminal; nothing off one)."),
    print_all: bool = typer.Option(False, "--print", help="Print the whole report (default: its verdict and the path of report.md)."),
) -> None:
    """Write DIR/report.md (verdict first, each caveat once, Tables I/II layout, paired 95 % intervals, published values; docs/report.md) and figures; print the verdict."""
    with Status("nespm report", enabled=not no_progress, plain=False) as status:  # phases: experiments.progress.phase
        status("loading the report modules")
        from nespm_cli.reports.dispatch import write_report

        path = write_report(out_dir, baseline, n_boot=n_boot, practical_pct=practical, beside=tuple(beside or ()),
                            all_runs=all_runs, consistent_share=consistent_share,
                            figure_jobs=None)  # a second process draws half the tracks' figures where there are 2 cores
    text = path.read_text(encoding="utf-8")
    if print_all:
        typer.echo(text)
        typer.echo(f"wrote {path}")
        return
    for line in report_summary(text):
        typer.echo(line)
    typer.echo(f"wrote {path} ({len(text.splitlines())} lines; --print shows it all)")


SUMMARY_CHARS = 300  # a summary's paragraph is cut to this many characters


def cells(row: str) -> list[str]:
    """The cells of a markdown table row ``| a | b |``."""
    return [c.strip() for c in row.strip().strip("|").split("|")]


def report_summary(text: str) -> list[str]:
    """What ``nespm report`` prints of a report's markdown ``text``: its title, then its verdict, one line
    per row of the verdict table (``Metric: best vs runner-up, improvement: verdict``); a report without a
    verdict section (tune, gp-ukf) gives its first paragraph (at most :data:`SUMMARY_CHARS` characters)."""
    lines = text.splitlines()
    title = next((x[2:].strip() for x in lines if x.startswith("# ")), "nespm report")
    start = next((i + 1 for i, x in enumerate(lines) if x.strip() == "## Verdict"), None)
    if start is None:
        start = next((i + 1 for i, x in enumerate(lines) if x.startswith("# ")), 0)
    end = next((i for i in range(start, len(lines)) if lines[i].startswith("## ")), len(lines))
    body = lines[start:end]
    table = [x for x in body if x.startswith("|")]
    if len(table) > 2:
        head = cells(table[0])
        col = {h.lower(): i for i, h in enumerate(head)}
        out = [f"{title}: verdict"]
        for row in table[2:]:
            c = cells(row)

            def get(name: str, c=c) -> str:
                return c[col[name]] if name in col and col[name] < len(c) else ""
            metric = get("metric") or c[0]
            value = f"value {c[0]}, " if head[0].lower() != "metric" and "metric" in col else ""
            said = get("verdict") or " | ".join(c[1:])
            best, runner, imp = get("best filter"), get("runner-up"), get("improvement over the runner-up [95 % ci]")
            rival = f" vs {runner}" if runner not in ("", "—") else ""
            pair = f" {best}{rival}" + (f", {imp}" if imp not in ("", "—") else "") + ":" if best else ""
            out.append(f"  {value}{metric}:{pair} {said}")
        return out
    para = []
    for x in body:
        if x.strip() and not x.startswith(("|", "!", "#")):
            para.append(x.strip())
        elif para:
            break
    words = " ".join(para)
    return [title] + ([words if len(words) <= SUMMARY_CHARS else words[:SUMMARY_CHARS - 3] + "..."] if words else [])


def compare(
    folders: List[Path] = typer.Argument(..., help="Two or more 'nespm mc' folders on the same realizations (same seed, tracks, runs, corruption, data): the cases."),
    out: str = typer.Option("results/compare", "--out", help="Folder for compare.md and figures/compare.png."),
    labels: Optional[str] = typer.Option(None, "--labels", help="Comma list of case names, one per folder (default: the folder names)."),
    reference: Optional[str] = typer.Option(None, "--reference", help="The case the others are compared with (default: the first)."),
    n_boot: int = typer.Option(2000, "--n-boot", help="Paired bootstrap resamples for the 95 % intervals."),
    no_progress: bool = typer.Option(False, "--no-progress", help="Do not say what is being done (a status on a terminal; nothing off one)."),
) -> None:
    """Compare cases (sensor suites, tunings) run on the same realizations: one table per case and filter, paired improvements over the reference case."""
    names = [x.strip() for x in labels.split(",")] if labels else None
    with Status("nespm compare", enabled=not no_progress, plain=False) as status:
        status("loading the report modules")
        from nespm_cli.reports.cases_report import write_compare_report

        path = write_compare_report(folders, non_empty_out(out), names, reference, n_boot=n_boot)
    typer.echo(path.read_text(encoding="utf-8"))
    typer.echo(f"wrote {path}")


def export(
    folder: Path = typer.Argument(..., help="A finished 'nespm mc' or 'nespm sweep' folder."),
    fmt: str = typer.Option("csv", "--format", help="csv (one file per table) or mat (one MATLAB .mat, a struct per table)."),
    out: Optional[str] = typer.Option(None, "--out", help="Output folder (default FOLDER/export)."),
    series: bool = typer.Option(False, "--series", help="Also the per-run per-epoch errors of the chunk series files (large)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace existing output files."),
) -> None:
    """Export metrics, epochs (and --series) as CSV or a MATLAB .mat file (docs/results-schema.md)."""
    from nespm_cli.reports.export import export_folder

    for p in export_folder(folder, fmt, None if out is None else non_empty_out(out), series, overwrite):
        typer.echo(f"wrote {p}")
