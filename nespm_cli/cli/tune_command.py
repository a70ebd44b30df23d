"""``nespm tune``: every filter's noise parameters searched with the same budget (docs/tuning.md)."""
from __future__ import annotations

import time
from pathlib import Path
from typing import List, Optional

import typer

from nespm_cli.cli.options import COMMON, KERNELS, with_options
from nespm_cli.cli.config import ARGV
from nespm_cli.cli.parsing import build_spec, check_jobs, parse_filters, parse_tracks
from nespm_cli.cli.result_commands import non_empty_out

TUNE = [  # (name, type, default, flag, help)
    ("tracks_", str, "1 2 3 4", "--tracks", "Tuning (training) tracks: --tracks 1 2 3 4 or 1,2,3,4."),
    ("runs", int, 20, "--runs", "Training runs per track and trial (the same realizations for every trial and filter)."),
    ("filters_", str, "ekf,ukf,ukf-nespm", "--filters", "Comma list of the filters to tune, each with the same budget."),
    ("trials", int, 50, "--trials", "Trials per filter (the budget; a rerun with more continues the studies)."),
    ("objective", str, "rmse-consistent", "--objective", "rmse-consistent (the most accurate settings whose ANEES lies in its band), rmse, consistency (every block's ANEES and sensor's ANIS near its expectation), or innovation (the filter's innovation likelihood: no truth read; docs/tuning.md)."),
    ("level", Optional[str], None, "--level", "With rmse-consistent: tracks (default; the common level of Q, R and P0 set in closed form so the geometric mean over the training tracks of each track's ANEES is its expectation, the search sets their ratios) or off (the level searched with the factors, a band penalty on the ANEES)."),
    ("level_runs", int, 100, "--level-runs", "With --level tracks: training runs per track the best settings' level is fitted on (more runs than the trials' make the level's sampling spread small)."),
    ("sampler", str, "tpe", "--sampler", "Optuna sampler of the global search: tpe (seeded, multivariate) or cmaes (needs the cmaes package)."),
    ("refine_trials", Optional[int], None, "--refine-trials", "Budget per filter of the local refinement after the global search (from the best of the filter's own and the other filters' values: a quadratic model's trust-region search (BOBYQA), then polls until no step improves the score by more than 0.5 %); default 17 per searched parameter and one; 0: none. The report says per filter converged or stopped short by X %."),
    ("search_seed", Optional[int], None, "--search-seed", "Seed of the samplers (the search's luck), apart from --seed (the data's); default: the training seed derived from --seed."),
    ("repeats", int, 1, "--repeats", "Independent searches per filter on the same training runs (search k's seed from --search-seed); the report gives each search's held-out score and whether the ranking survives the search's spread."),
    ("pick", str, "best", "--pick", "With --repeats: which search's values tuned.toml (and the held-out 'tuned' runs) hold per filter: best (the lowest training score: the searches' luck taken out of the result) or first (search 0). Every search's values stay in tune.json; docs/tuning.md."),
    ("flat", str, "default", "--flat", "What a parameter the objective cannot see (flat profile: < 2 % at x3 and /3) becomes: default (back to its default where the training score stays within 2 %; docs/tuning.md 'Flat parameters') or searched (the best trial's value)."),
    ("storage", Optional[str], None, "--storage", "An Optuna RDB storage URL every worker reaches (e.g. postgresql://user@host/db) instead of the journal file OUT/study.journal (docs/cluster.md)."),
    ("tune_range", Optional[List[str]], None, "--tune-range", "NAME.KEY=LOW:HIGH narrows or widens a parameter's range (NAME * for every filter), NAME.KEY=off drops it; a range on a sensor's lever arm turns its search on ('*.lever_arm_x_dvl=-3:3': each filter calibrates the DVL's fore-aft offset, linear); repeatable; a [tune] table in a --config file."),
    ("test_tracks_", str, "", "--test-tracks", "Held-out tracks, run with the default and the tuned settings on --seed's realizations (e.g. --test-tracks 5 6)."),
    ("test_runs", int, 100, "--test-runs", "Held-out runs per test track."),
    ("allow_overlap", bool, False, "--allow-overlap", "Allow test tracks among the tuning tracks (the report flags it)."),
    ("no_profile", bool, False, "--no-profile", "Skip the score profile and the importance (fANOVA) of each tuned parameter (2 trials per parameter after the search; the report's profile and importance columns then read —, and no importance.png)."),
    ("jobs", int, 1, "--jobs", "Worker processes (a process per filter and search when there are at least as many: the values of --jobs 1, bit for bit); with --backend dask the local cluster's workers."),
    ("backend", str, "loky", "--backend", "Where the searches run: loky (local processes) or dask (a task per filter and search on a Dask cluster, the studies in OUT/study.journal or --storage; docs/cluster.md)."),
    ("scheduler", Optional[str], None, "--scheduler", "Dask scheduler address (tcp://host:8786) or scheduler file; default $NESPM_DASK_SCHEDULER, else a local cluster of --jobs workers."),
    ("no_progress", bool, False, "--no-progress", "No line per 10 trials."),
    ("config", Optional[str], None, "--config", "TOML file of options; [filters.NAME] and [tune] tables (docs/tuning.md)."),
]


@with_options(TUNE, COMMON, [KERNELS])
def tune(
    out: str = typer.Option("results/tune", "--out", help="Output folder (study.journal, trials.parquet, tuned.toml, tune.json; resumable)."),
    **kw,
) -> None:
    """Tune every filter's noise (Q, R, P0, alpha) with the same budget on training runs; write tuned.toml."""
    from nespm_cli.reports.tune.searches import convergence_word
    from nespm_cli.tuning.run import run_tune
    from nespm_cli.tuning.spec import TuneSpec
    from nespm_cli.tuning.progress import echo_progress
    from nespm_cli.tuning.heldout import run_heldout
    from nespm_cli.tuning.space import parse_range
    from nespm_cli.experiments.folder_kind import refuse_other_kind

    kw.pop("config")
    check_jobs(kw["jobs"])
    refuse_other_kind(non_empty_out(out), "tune")
    t0 = time.perf_counter()
    test = kw.pop("test_tracks_").strip()
    opts = dict(trials=kw.pop("trials"), objective=kw.pop("objective").lower(), sampler=kw.pop("sampler").lower(),
                level=(kw.pop("level") or "").lower() or None, level_runs=kw.pop("level_runs"),
                ranges=tuple(parse_range(r) for r in kw.pop("tune_range") or ()),
                test_tracks=parse_tracks(test) if test else (), test_runs=kw.pop("test_runs"),
                allow_overlap=kw.pop("allow_overlap"), profile=not kw.pop("no_profile"),
                refine_trials=kw.pop("refine_trials"), search_seed=kw.pop("search_seed"), repeats=kw.pop("repeats"),
                storage=kw.pop("storage"), flat=kw.pop("flat").lower(), pick=kw.pop("pick").lower())
    jobs, quiet = kw.pop("jobs"), kw.pop("no_progress")
    backend, scheduler = kw.pop("backend").lower(), kw.pop("scheduler")
    spec = build_spec(tracks=parse_tracks(kw.pop("tracks_")), runs=kw.pop("runs"),
                      filters=parse_filters(kw.pop("filters_")), **kw)
    t = TuneSpec(spec, **opts)

    record = run_tune(t, out, jobs=jobs, report=None if quiet else echo_progress(t.trials), argv=("nespm", *ARGV),
                      backend=backend, scheduler=scheduler)
    for f, b in record["best"].items():
        d = b["default_score"]
        c = b.get("convergence") or {}
        said = convergence_word(c)
        typer.echo((f"{f}: score {d:.6g} (default) -> {b['score']:.6g} (trial {b['trial']})" if d is not None
                    else f"{f}: best score {b['score']:.6g} (trial {b['trial']})") + (f"; {said}" if said else ""))
    if t.test_tracks:
        if not quiet:
            typer.echo(f"held out: tracks {' '.join(map(str, t.test_tracks))}, {t.test_runs} runs, default and tuned",
                       err=True)
        run_heldout(spec, record, out, jobs=jobs, progress=not quiet, backend=backend, scheduler=scheduler)
    typer.echo(f"{t.trials} trials per filter in {time.perf_counter() - t0:.1f} s -> {out}/tuned.toml; "
               f"next: nespm mc --config {out}/tuned.toml{plugin_words(spec, Path(out) / 'tuned.toml')}"
               + (f"; nespm report {out}" if t.test_tracks else ""))


def plugin_words(spec, toml: Path) -> str:
    """`` --filter-plugin P --sensor-plugin Q`` for the study's plugins that ``toml`` (``tuned.toml``) does
    not record itself (``filter_plugin`` / ``sensor_plugin`` keys): the suggested next command must load
    the filters and sensors the file's tables name."""
    import shlex

    try:
        text = toml.read_text(encoding="utf-8")
    except OSError:
        text = ""
    return "".join(f" --{key.replace('_', '-')} {shlex.quote(str(p))}"
                   for key, items in (("filter_plugin", spec.filter_plugins), ("sensor_plugin", spec.sensor_plugins))
                   if f"\n{key} = " not in f"\n{text}" for p in items)
