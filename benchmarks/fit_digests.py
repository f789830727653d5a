"""Digests of every fit the calibration's estimators return while tests run, to show that a change leaves them alone.

A pytest plugin: ``FIT_DIGESTS=OUT.txt python -m pytest -p fit_digests -p no:xdist tests/unit/test_calibration_lidar.py
...`` appends one line per call of :func:`~pipeline.calibration.lidar.estimate_lidar`,
:func:`~pipeline.calibration.actuation.estimate_actuation`, :func:`~pipeline.calibration.network.estimate_network` and
:func:`~pipeline.calibration.motors.estimate_motors` made by a test module that imports it by name: the estimator, the
test and the sha256 of the fit (every field of its dataclasses, arrays by dtype, shape and bytes, floats by their
repr). Run it on two commits (``PYTHONPATH=WORKTREE`` for the other) and compare the sorted files: the same lines
mean the same fits to the byte. The plugin wraps the estimators before the test modules import them; calls made
through the calibration's steps (imported with the package) are not wrapped.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from collections.abc import Callable
from typing import Any

import numpy as np

import pipeline.calibration.actuation as actuation
import pipeline.calibration.lidar as lidar
import pipeline.calibration.motors as motors
import pipeline.calibration.network as network

ESTIMATORS = (
    (lidar, "estimate_lidar"),
    (actuation, "estimate_actuation"),
    (network, "estimate_network"),
    (motors, "estimate_motors"),
)


def feed(h: Any, value: object) -> None:
    """Everything in `value` into the hash `h`, field by field."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        h.update(type(value).__name__.encode())
        for f in dataclasses.fields(value):
            h.update(f.name.encode())
            feed(h, getattr(value, f.name))
    elif isinstance(value, np.ndarray):
        h.update(f"{value.dtype}{value.shape}".encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, list | tuple):
        h.update(b"(")
        for v in value:
            feed(h, v)
        h.update(b")")
    elif isinstance(value, dict):
        for k in sorted(value, key=repr):
            h.update(repr(k).encode())
            feed(h, value[k])
    else:
        h.update(repr(value).encode())


def digested(name: str, estimator: Callable[..., Any], out: str) -> Callable[..., Any]:
    def call(*args: Any, **kwargs: Any) -> Any:
        fit = estimator(*args, **kwargs)
        h = hashlib.sha256()
        feed(h, fit)
        test = os.environ.get("PYTEST_CURRENT_TEST", "?").split(" ")[0]
        with open(out, "a", encoding="utf-8") as file:
            file.write(f"{name} {test} {h.hexdigest()}\n")
        return fit

    return call


_OUT = os.environ.get("FIT_DIGESTS")
if _OUT:
    for _module, _name in ESTIMATORS:
        setattr(_module, _name, digested(_name, getattr(_module, _name), _OUT))
