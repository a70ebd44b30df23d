"""The track spec (``nespm-data.toml``, docs/data.md): a user's own files read as the bench's tracks. One
concept a module, each importing only the ones above it in this list (nothing calls back):

* :mod:`~nespm_cli.data.track_spec.units`: the units and their factors to SI, :func:`scaled`, :func:`to_seconds`;
* :mod:`~nespm_cli.data.track_spec.schema`: the TOML file's keys, read and checked (:func:`read_spec`,
  :class:`TrackSpec`, :func:`find_spec`);
* :mod:`~nespm_cli.data.track_spec.files`: each track's files in the data folder (:func:`spec_tracks`,
  :func:`spec_file`, :func:`spec_files`);
* :mod:`~nespm_cli.data.track_spec.convert`: one track's files read and converted (units, time base, frames,
  axes) into the A-KIT arrays (:func:`read_spec_track`, :class:`SpecTrack`; :func:`init_state` without ``[gt]``);
* :mod:`~nespm_cli.data.track_spec.data_checks`: the checks only a spec's data need (vertical signs, depth
  and fix files) and the messages in the file's own column names.

:func:`nespm_cli.data.tracks.load_track` uses them in that order, then runs the A-KIT checks. The package
re-exports the names other modules use.
"""
from __future__ import annotations

from nespm_cli.data.track_spec.convert import SpecTrack, init_state, labels, read_spec_track
from nespm_cli.data.track_spec.data_checks import (angle_hint, check_channel, check_vertical_sign, relabel,
                                                  stamps_checked)
from nespm_cli.data.track_spec.files import spec_file, spec_files, spec_tracks
from nespm_cli.data.track_spec.schema import SCHEMA, SPEC_NAME, TrackSpec, find_spec, read_spec
from nespm_cli.data.track_spec.units import STANDARD_GRAVITY, UNITS, scaled, to_seconds

__all__ = ["SPEC_NAME", "SCHEMA", "TrackSpec", "find_spec", "read_spec", "spec_tracks", "spec_file", "spec_files",
           "SpecTrack", "read_spec_track", "init_state", "labels", "angle_hint", "check_channel",
           "check_vertical_sign", "relabel", "stamps_checked", "STANDARD_GRAVITY", "UNITS", "scaled", "to_seconds"]
