"""Registry of the sensors by name: the built-ins (``dvl``, ``depth``, ``fix``, ``dvl-beams``, ``heading``)
and user plugins.

The same rules as the filters' (:class:`nespm_cli.plugins.Registry`): ``@register("name")`` on a
:class:`~nespm_cli.sensors.source.Sensor` subclass; ``--sensor-plugin FILE`` or an importable
module (:func:`load_plugin`); installed distributions declare entry points in the group
``nespm.sensors``. docs/sensors.md shows a plugin (``examples/usbl_sensor.py``).
"""
from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import Callable

from nespm_cli.plugins import Registry
from nespm_cli.sensors.depth import Depth
from nespm_cli.sensors.dvl import Dvl
from nespm_cli.sensors.dvl_beams import DvlBeams
from nespm_cli.sensors.fix import Fix
from nespm_cli.sensors.heading import Heading
from nespm_cli.sensors.source import Sensor

ENTRY_POINT_GROUP = "nespm.sensors"
SENSOR_REGISTRY = Registry("sensor", Sensor, ENTRY_POINT_GROUP, "--sensors")
for _name, _cls in (("dvl", Dvl), ("depth", Depth), ("fix", Fix), ("dvl-beams", DvlBeams), ("heading", Heading)):
    SENSOR_REGISTRY.register(_name, _cls)


def register(name: str) -> Callable[[type], type]:
    """Class decorator: ``@register("usbl") class Usbl(Sensor): ...``."""
    return SENSOR_REGISTRY.decorator(name)


def get_sensor(name: str) -> type:
    """The sensor class registered as ``name``."""
    return SENSOR_REGISTRY.get(name)


def sensor_names(builtin_only: bool = False) -> tuple[str, ...]:
    """Registered sensor names, built-ins first."""
    return SENSOR_REGISTRY.names(builtin_only)


def sensor_files(name: str) -> list[Path]:
    """The source files of a plugin sensor (empty for a built-in), for the manifest's hashes."""
    return SENSOR_REGISTRY.files(name)


def load_plugin(path_or_module: str | Path) -> ModuleType:
    """Import a sensor plugin (a ``.py`` file, or an importable module); return the module."""
    return SENSOR_REGISTRY.load_plugin(path_or_module)


def discover_plugins() -> list[str]:
    """Import every entry point of the group ``nespm.sensors``; runs once."""
    return SENSOR_REGISTRY.discover()


__all__ = ["ENTRY_POINT_GROUP", "SENSOR_REGISTRY", "discover_plugins", "get_sensor", "load_plugin", "register",
           "sensor_files", "sensor_names"]
