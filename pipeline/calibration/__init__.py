"""Calibration of the simulator's noise and actuation from deployment recordings.

:func:`calibrate` reads session recordings (MCAP, the session layout of :mod:`pipeline.record.session`
or a ``ros2 bag record -s mcap`` with the standard topics) and estimates the reality profile's lidar,
actuation, odometry and network values, each with an uncertainty and a status (``ok``, or
``unidentifiable`` with the reason). :func:`write_calibration` writes ``calibration.yaml`` (the
profile, the uncertainties, and the ``world`` overrides that training applies on top of params.yaml)
and a fit report with plots.

Modules: :mod:`~pipeline.calibration.recording` (reading), :mod:`~pipeline.calibration.smoothing`
(Kalman/RTS smoothing of ground truth), :mod:`~pipeline.calibration.raycast` (ranges in the known map),
:mod:`~pipeline.calibration.lidar`, :mod:`~pipeline.calibration.actuation`,
:mod:`~pipeline.calibration.odometry`, :mod:`~pipeline.calibration.network` (the estimators),
:mod:`~pipeline.calibration.calibrate`, :mod:`~pipeline.calibration.output` and
:mod:`~pipeline.calibration.fit_report`.
"""

from pipeline.calibration.calibrate import Calibration, Source, calibrate
from pipeline.calibration.errors import CalibrationError, ScenarioMismatchError
from pipeline.calibration.estimates import Estimate
from pipeline.calibration.keys import PROFILE_KEYS
from pipeline.calibration.options import PARTS, CalibrationSettings, calibration_settings
from pipeline.calibration.output import calibration_mapping, write_calibration
from pipeline.record.errors import MissingTopicError

__all__ = [
    "PARTS",
    "PROFILE_KEYS",
    "Calibration",
    "CalibrationError",
    "CalibrationSettings",
    "Estimate",
    "MissingTopicError",
    "ScenarioMismatchError",
    "Source",
    "calibrate",
    "calibration_mapping",
    "calibration_settings",
    "write_calibration",
]
