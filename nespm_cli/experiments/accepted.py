"""The convention residuals a study ran with although its data contradict the declared conventions.

A track whose data contradict its declared attitude or frame conventions (:mod:`nespm_cli.data.conventions`)
is refused unless ``--accept-residual`` (``Spec.accept_residual``) or its track spec's ``gt.accept_residual``
accepts it; the sentence of each accepted track is then kept in
:data:`nespm_cli.data.conventions.ACCEPTED` by the process that loaded it. :func:`accepted_residuals` picks
those of a study's tracks for the manifest's ``accepted_residuals`` (docs/results-schema.md), which the
report turns into one caveat per track (:func:`nespm_cli.reports.caveats.residual_caveats`).
"""
from __future__ import annotations

from typing import Iterable

from nespm_cli.data import conventions
from nespm_cli.experiments.spec import Spec, track_inputs


def residual_key(folder: str, number: int) -> str:
    """The manifest's key of track ``number`` read from ``folder`` (its truth file's folder): ``<folder>#<number>``."""
    return f"{folder}#{int(number)}"


def accepted_residuals(specs: Iterable[Spec]) -> dict[str, str]:
    """``{"<folder>#<track>": sentence}`` of every track of the validated ``specs`` loaded with a contradiction
    accepted in this process (:data:`~nespm_cli.data.conventions.ACCEPTED`); ``{}`` when none was (an embedded
    track is never checked). The folder is the track's ``source``, the folder of its truth file."""
    out: dict[str, str] = {}
    numbers = {n for _, n in conventions.ACCEPTED}
    for spec in specs:
        if spec.data_dir is None:
            continue
        for n in (n for n in spec.tracks if int(n) in numbers):  # no track read for nothing
            source = track_inputs(spec, n)[0].source  # read once per process: no second read
            text = conventions.ACCEPTED.get((source, int(n)))
            if text is not None:
                out[residual_key(source, n)] = text
    return out


__all__ = ["accepted_residuals", "residual_key"]
