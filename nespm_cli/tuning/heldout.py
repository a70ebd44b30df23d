"""The held-out evaluation of ``nespm tune``: the test tracks run with the default and with the tuned
settings of every filter, on the same realizations (``--seed``, runs ``0 .. --test-runs-1``), as two
``mc`` folders inside the tuning folder: ``OUT/heldout-default`` and ``OUT/heldout-tuned``
(resumable like any ``mc``; ``nespm compare`` pairs them run by run). The tuned one is exactly
``nespm mc --config OUT/tuned.toml --tracks TEST --runs N --seed S`` with the study's options.
With ``--repeats K`` each search k has its own tuned folder on the same realizations (:func:`tuned_dir`):
``OUT/heldout-tuned-search{k}``, the first search's ``OUT/heldout-tuned`` itself where ``tuned.toml`` holds
its values for every filter (``--pick first``, or the first search the best of every filter's).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

from nespm_cli.experiments.backend import Execution
from nespm_cli.experiments.spec import Spec
from nespm_cli.filters.options import TUNED_ON, tuned_on_text

DEFAULT_DIR, TUNED_DIR = "heldout-default", "heldout-tuned"


def tuned_options(spec: Spec, best: dict, tuned_on: str) -> tuple:
    """``spec.filter_options`` with every filter's tuned values (``best`` of ``tune.json``) and
    ``tuned_on`` over them: the options ``mc --config tuned.toml`` runs with."""
    tuned = {(f, k): float(v) for f, b in best.items() for k, v in b["values"].items()}
    tuned.update({(f, TUNED_ON): tuned_on for f in best})
    keep = tuple(o for o in spec.filter_options if (o[0], o[1]) not in tuned)
    return keep + tuple((f, k, v) for (f, k), v in tuned.items())


def picked_elsewhere(record: dict) -> bool:
    """Whether ``tuned.toml`` (``record["best"]``) holds another search's values than the first's for some
    filter (``record["picked"]``, ``{filter: search}``, :func:`nespm_cli.tuning.run.pick_searches`)."""
    return any(int(k) != 0 for k in (record.get("picked") or {}).values())


def tuned_dir(search: int = 0, record: dict | None = None) -> str:
    """The held-out folder of search ``search``'s tuned values (``--repeats``): ``heldout-tuned`` for the
    first where ``tuned.toml`` holds its values (``record`` None, or :func:`picked_elsewhere` False),
    ``heldout-tuned-search{k}`` otherwise."""
    if search == 0 and not picked_elsewhere(record or {}):
        return TUNED_DIR
    return f"{TUNED_DIR}-search{search}"


def search_best(record: dict, search: int | None) -> dict:
    """``{filter: {"values": ...}}`` of search ``search`` of a ``tune.json`` record, or (None) of ``tuned.toml``
    (``record["best"]``)."""
    if search is None or "searches" not in record:
        return record["best"]
    return {f: {"values": runs[search]["values"]} for f, runs in record["searches"].items()}


def heldout_specs(spec: Spec, record: dict, search: int | None = None) -> tuple[Spec, Spec]:
    """``(default, tuned)``: the held-out study (``record["test"]`` of ``tune.json``) with the study's
    options, and with the tuned ones of ``tuned.toml`` (``search`` None) or of search ``search``."""
    test, on = record["test"], record["tuned_on"]
    base = dataclasses.replace(spec, tracks=tuple(test["tracks"]), runs=int(test["runs"]), smooth=())
    where = tuned_on_text(on["seed"], on["tracks"], on["runs"][0], on["runs"][1])
    return base, dataclasses.replace(base, filter_options=tuned_options(spec, search_best(record, search), where))


def run_heldout(spec: Spec, record: dict, out: str | Path, jobs: int = 1, progress: bool = False,
                backend: str = "loky", scheduler: str | None = None) -> dict:
    """Run the held-out folders (resuming them): the default, ``tuned.toml``'s values and each search's tuned
    values not already among them; return ``{"default": metrics, "tuned": metrics, "tuned-search{k}": metrics,
    ...}``."""
    from nespm_cli.experiments.mc import run_mc

    ex = Execution(jobs=jobs, backend=backend, scheduler=scheduler, progress=progress)
    out = Path(out)
    default, tuned = heldout_specs(spec, record)
    res = {"default": run_mc(default, out / DEFAULT_DIR, ex), "tuned": run_mc(tuned, out / TUNED_DIR, ex)}
    for k in range(int(record.get("repeats", 1))):
        if tuned_dir(k, record) != TUNED_DIR:
            res[f"tuned-search{k}"] = run_mc(heldout_specs(spec, record, k)[1], out / tuned_dir(k, record), ex)
    return res


__all__ = ["DEFAULT_DIR", "TUNED_DIR", "heldout_specs", "picked_elsewhere", "run_heldout", "search_best", "tuned_dir",
           "tuned_options"]
