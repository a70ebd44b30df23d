"""sensors: measurement sources (layer below filters): what a sensor measures, when, how it is
synthesized from the truth or read from a track, and its model ``(z, h, H, R)`` (docs/sensors.md)."""
from nespm_cli.sensors.measurement import Measurement
from nespm_cli.sensors.registry import get_sensor, register, sensor_names
from nespm_cli.sensors.source import Channel, Context, Sensor, SensorOptions, TrackInfo, Truth

__all__ = ["Channel", "Context", "Measurement", "Sensor", "SensorOptions", "TrackInfo", "Truth", "get_sensor",
           "register", "sensor_names"]
