"""The sensor suite of an experiment: which sensors, with which options, built and checked once.

``Spec.sensors`` names the sources in update order (``--sensors dvl,depth,fix``);
``Spec.sensor_options`` holds ``(sensor, key, value)`` triples (``--sensor-option fix.std=2``, a
config file's ``[sensors.fix]`` table). The papers' DVL flags are the DVL's defaults here, so an
old command keeps its numbers: ``--dvl`` is ``dvl.source``, ``--dvl-noise`` ``dvl.std``,
``--dvl-r-std`` ``dvl.r_std``, ``--dvl-lever-arm`` ``dvl.lever_arm`` and ``--scenario outage``
(``--outage-start``, ``--outage-length``) ``dvl.outage``; a ``--sensor-option`` for the same key
overrides them. Every sensor's resolved options go into the manifest (:func:`suite_record`).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

from nespm_cli.errors import NespmError
from nespm_cli.nav.state import StateLayout
from nespm_cli.sensors.channels import probe
from nespm_cli.sensors.guard import make_sensor
from nespm_cli.sensors.registry import SENSOR_REGISTRY, get_sensor, sensor_files, sensor_names
from nespm_cli.sensors.source import Sensor, options_of


def load_sensors(spec):
    """Import the spec's sensor plugins and the ``nespm.sensors`` entry points (idempotent; in the
    parent and in every worker); return the spec with plugin files as absolute paths."""
    return dataclasses.replace(spec, sensor_plugins=SENSOR_REGISTRY.load_plugins(spec.sensor_plugins))


def legacy_options(spec) -> dict:
    """The DVL options the papers' flags give (see the module docstring)."""
    out = {"source": spec.dvl, "std": spec.corruption.dvl_noise, "lever_arm": tuple(spec.dvl_lever_arm)}
    if spec.dvl_r_std is not None:
        out["r_std"] = spec.dvl_r_std
    if spec.scenario == "outage":
        out["outage"] = f"{spec.outage_start:g}:{spec.outage_start + spec.outage_length:g}"
    return out


def raw_options(spec) -> dict[str, dict]:
    """``{sensor: {key: value}}``: the legacy DVL options, then ``spec.sensor_options`` over them."""
    raw: dict[str, dict] = {name: {} for name in spec.sensors}
    if "dvl" in raw:
        raw["dvl"].update(legacy_options(spec))
    for name, key, value in spec.sensor_options:
        if name not in raw:
            raise NespmError(f"--sensor-option {name}.{key}: {name} is not in --sensors "
                             f"({','.join(spec.sensors)}); add it there or drop the option")
        raw[name][key] = value
    return raw


def sensor_suite(spec) -> list[Sensor]:
    """The sensors of ``spec`` in update order, each with its checked options (one-line errors)."""
    names = sensor_names()
    if not spec.sensors:
        raise NespmError("--sensors: give at least one sensor (e.g. dvl)")
    for name in spec.sensors:
        if name not in names:
            raise NespmError(f"--sensors: unknown sensor {name!r}; choose from {', '.join(names)} "
                             "(or load one with --sensor-plugin)")
    if len(set(spec.sensors)) != len(spec.sensors):
        raise NespmError("--sensors: give each sensor once")
    raw = raw_options(spec)
    return [make_sensor(get_sensor(name), options_of(get_sensor(name), raw[name])) for name in spec.sensors]


def dvl_of(spec) -> Sensor | None:
    """The DVL of ``spec`` with its resolved options (legacy flags and ``--sensor-option``), or None."""
    if "dvl" not in spec.sensors:
        return None
    cls = get_sensor("dvl")
    return cls(options_of(cls, raw_options(spec)["dvl"]))


def check_suite(spec, layout: StateLayout, tracks: dict, truths: dict | None = None) -> list[Sensor]:
    """Check the suite against the layout and the data: each sensor sees only blocks the layout
    holds; a recorded source exists on every track (``tracks``: ``{number: Track}``); the outage
    scenario needs the DVL; with ``truths`` (``{number: ImuTruth}``) each sensor's times and values
    on every track (:func:`nespm_cli.sensors.channels.probe`). Returns the suite."""
    suite = sensor_suite(spec)
    if spec.scenario == "outage" and "dvl" not in spec.sensors:
        raise NespmError("--scenario outage cuts the DVL, which is not in --sensors; add dvl or use "
                         "--sensor-option NAME.outage=START:END")
    for s in suite:
        s.check(layout)
        if s.opt.source == "recorded":
            for n, track in tracks.items():
                if s.recorded(track) is None:
                    raise NespmError(f"--sensors {s.name}: source recorded, but track {n} has no {s.name} file "
                                     f"(docs/data-format.md); use --sensor-option {s.name}.source=synthetic")
    for n, truth in (truths or {}).items():
        for s in suite:
            probe(s, tracks[n], truth, spec.seed, n)
    return suite


def suite_record(spec) -> dict:
    """``{sensor: {option: value}}`` of the resolved options (the manifest's ``sensors``)."""
    out = {}
    for s in sensor_suite(spec):
        d = dataclasses.asdict(s.opt)
        d["lever_arm"] = list(d["lever_arm"])
        d["filter_std"] = s.r_std()
        d["dim"] = int(s.dim)  # the NIS's dof: reports read it here, without the plugin
        out[s.name] = d
    return out


def recorded_dim(manifest: dict, name: str) -> int | None:
    """The dimension m of sensor ``name`` as the manifest's ``sensors`` record it (:func:`suite_record`,
    per cell): the one value every cell holding it agrees on, else None (not recorded: a folder made
    before nespm recorded it; or cells that disagree)."""
    cells = [c for c in (manifest.get("sensors") or {}).values() if isinstance(c, dict)]
    dims = {c[name].get("dim") for c in cells if isinstance(c.get(name), dict)}
    ok = {d for d in dims if isinstance(d, int) and not isinstance(d, bool) and d >= 1}
    return ok.pop() if len(ok) == 1 and len(dims) == 1 else None


def sensor_plugin_files(spec) -> list[Path]:
    """The source files of the spec's plugin sensors (for the manifest's hashes)."""
    return [p for name in spec.sensors for p in sensor_files(name)]


__all__ = ["check_suite", "dvl_of", "legacy_options", "load_sensors", "raw_options", "recorded_dim", "sensor_plugin_files", "sensor_suite",
           "suite_record"]
