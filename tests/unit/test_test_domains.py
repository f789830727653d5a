"""The suite's DDS domain ids: disjoint between the workers of a parallel run, never the default domain."""

from __future__ import annotations

import pytest

from tests.domains import BANDS, domain_id


@pytest.mark.parametrize("workers", [1, 2, 3])
def test_the_workers_of_a_run_draw_from_disjoint_shares_of_each_band(monkeypatch, workers):
    monkeypatch.setenv("PYTEST_XDIST_WORKER_COUNT", str(workers))
    for band, (first, end) in BANDS.items():
        drawn = []
        for k in range(workers):
            monkeypatch.setenv("PYTEST_XDIST_WORKER", f"gw{k}")
            drawn.append({domain_id(band, salt) for salt in range(500)})
        for k, ids in enumerate(drawn):
            assert min(ids) >= first and max(ids) < end and 0 not in ids, band
            assert all(not ids & other for other in drawn[k + 1 :]), (band, k)
