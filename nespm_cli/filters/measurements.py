"""Where plugins written before the sensors package found the measurement interface.

The measurement protocol now lives in :mod:`nespm_cli.sensors.measurement` and the DVL's model in
:mod:`nespm_cli.sensors.dvl` (docs/sensors.md); this module re-exports both names so a filter
plugin importing them from here keeps working.
"""
from nespm_cli.sensors.dvl import DvlMeasurement
from nespm_cli.sensors.measurement import Measurement

__all__ = ["DvlMeasurement", "Measurement"]
