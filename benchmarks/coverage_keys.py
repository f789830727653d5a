"""The keys of coverage rows, one per truth where pooled runs scored a key against different truths (the benchmark's
summary and the README's tables read them alike)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any


def split_by_truth(rows: Sequence[Mapping[str, Any]]) -> tuple[list[str], list[dict[str, Any]]]:
    """(keys in first-seen order, rows): a key that rows score against more than one truth (``truth_of``, "profile"
    where absent) becomes ``"<key> (<truth>)"``, one per truth, in its rows and in the keys."""
    truths: dict[str, set[str]] = {}
    for r in rows:
        truths.setdefault(str(r["key"]), set()).add(str(r.get("truth_of") or "profile"))
    keys = [f"{key} ({t})" if len(found) > 1 else key for key, found in truths.items() for t in sorted(found)]
    out = [
        {**r, "key": f"{r['key']} ({r.get('truth_of') or 'profile'})"} if len(truths[str(r["key"])]) > 1 else dict(r)
        for r in rows
    ]
    return keys, out
