"""benchmarks/fit_digests.py: a fit's digest is the same for the same fit and differs for a change of one bit."""

from __future__ import annotations

import hashlib

import numpy as np
from fit_digests import feed

from pipeline.calibration.estimates import Estimate


def digest(value: object) -> str:
    h = hashlib.sha256()
    feed(h, value)
    return h.hexdigest()


def test_a_fit_s_digest_holds_every_field_to_the_bit():
    est = Estimate.of(0.02, 0.001, (0.018, 0.022), "m", "bootstrap", 40)
    again = Estimate.of(0.02, 0.001, (0.018, 0.022), "m", "bootstrap", 40)
    assert digest((est, np.arange(3.0), {"a": [1, 2]})) == digest((again, np.arange(3.0), {"a": [1, 2]}))
    assert digest(est) != digest(Estimate.of(np.nextafter(0.02, 1.0), 0.001, (0.018, 0.022), "m", "bootstrap", 40))
    assert digest(np.arange(3.0)) != digest(np.arange(3.0).astype(np.float32))  # the dtype counts
    assert digest(est) != digest(Estimate.of(0.02, 0.001, (0.018, 0.022), "m", "other words", 40))
