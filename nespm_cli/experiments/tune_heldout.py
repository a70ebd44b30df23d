"""The held-out evaluation of ``nespm tune``: the test tracks run with the default and with the tuned
settings of every filter, on the same realizations (``--seed``, runs ``0 .. --test-runs-1``), as two
``mc`` folders inside the tuning folder: ``OUT/heldout-default`` and ``OUT/heldout-tuned``
(resumable like any ``mc``; ``nespm compare`` pairs them run by run). The tuned one is exactly
``nespm mc --config OUT/tuned.toml --tracks TEST --runs N --seed S`` with the study's options.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

from nespm_cli.experiments.backend import Execution
from nespm_cli.experiments.spec import Spec

DEFAULT_DIR, TUNED_DIR = "heldout-default", "heldout-tuned"


def tuned_options(spec: Spec, best: dict) -> tuple:
    """``spec.filter_options`` with every filter's tuned values (``best`` of ``tune.json``) over them."""
    tuned = {(f, k): float(v) for f, b in best.items() for k, v in b["values"].items()}
    keep = tuple(o for o in spec.filter_options if (o[0], o[1]) not in tuned)
    return keep + tuple((f, k, v) for (f, k), v in tuned.items())


def heldout_specs(spec: Spec, test_tracks: tuple, test_runs: int, best: dict) -> tuple[Spec, Spec]:
    """``(default, tuned)``: the held-out study with the study's options, and with the tuned ones."""
    base = dataclasses.replace(spec, tracks=tuple(test_tracks), runs=int(test_runs), smooth=())
    return base, dataclasses.replace(base, filter_options=tuned_options(spec, best))


def run_heldout(spec: Spec, record: dict, out: str | Path, jobs: int = 1, progress: bool = False) -> dict:
    """Run both held-out folders (resuming them); return ``{"default": metrics, "tuned": metrics}``."""
    from nespm_cli.experiments.mc import run_mc

    test = record["test"]
    default, tuned = heldout_specs(spec, tuple(test["tracks"]), test["runs"], record["best"])
    ex = Execution(jobs=jobs, progress=progress)
    out = Path(out)
    return {"default": run_mc(default, out / DEFAULT_DIR, ex), "tuned": run_mc(tuned, out / TUNED_DIR, ex)}


__all__ = ["DEFAULT_DIR", "TUNED_DIR", "heldout_specs", "run_heldout", "tuned_options"]
