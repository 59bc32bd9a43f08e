"""The kept sets of simplify_points on the shared scans: the regression oracle of the core.

For method km and fcm and the rules threshold, iterative, target(0.5),
iterative(0.5) and coverage(0.5), seed 0, on bun_zipper.ply, maxplanck.ply and
autzen_trim.laz: the kept count and the first 16 hex digits of the sha256 of
the sorted kept indices (int64 bytes) equal those recorded on main before the
split of core/ into one file per stage. A change of the method that changes a
kept set shows here.
"""

from __future__ import annotations

import functools
import hashlib

import numpy as np
import pytest
from conftest import shared_file

from cloudsieve.core import simplify_points
from cloudsieve.io import read_cloud

# (file, method, rule, ratio): (kept count, sha256(sorted kept indices as int64)[:16])
KEPT = {
    ("bun_zipper.ply", "km", "threshold", None): (35201, "15d275799f89f252"),
    ("bun_zipper.ply", "km", "iterative", None): (35774, "728a0c554c38dce6"),
    ("bun_zipper.ply", "km", "target", 0.5): (17974, "cb35a8747260e3c6"),
    ("bun_zipper.ply", "km", "iterative", 0.5): (17974, "6b0ff12397d0b71e"),
    ("bun_zipper.ply", "km", "coverage", 0.5): (17974, "fc2ce4b493ef86e3"),
    ("bun_zipper.ply", "fcm", "threshold", None): (35227, "0b01a722ed584aff"),
    ("bun_zipper.ply", "fcm", "iterative", None): (35759, "d8a43864b72d30d8"),
    ("bun_zipper.ply", "fcm", "target", 0.5): (17974, "46b9df450236f817"),
    ("bun_zipper.ply", "fcm", "iterative", 0.5): (17974, "969af6e4cb690f5c"),
    ("bun_zipper.ply", "fcm", "coverage", 0.5): (17974, "c96def1c5640f6b9"),
    ("maxplanck.ply", "km", "threshold", None): (22678, "f27910fb6ce6088a"),
    ("maxplanck.ply", "km", "iterative", None): (23437, "fc92710469bb9c53"),
    ("maxplanck.ply", "km", "target", 0.5): (12722, "05b84b036e8c727b"),
    ("maxplanck.ply", "km", "iterative", 0.5): (12722, "026636afe50a9ea9"),
    ("maxplanck.ply", "km", "coverage", 0.5): (12722, "88db442a1a1d9c78"),
    ("maxplanck.ply", "fcm", "threshold", None): (22841, "275128010436ee40"),
    ("maxplanck.ply", "fcm", "iterative", None): (23573, "a81e9a1af646e4a6"),
    ("maxplanck.ply", "fcm", "target", 0.5): (12722, "237eadfeb21eaeaf"),
    ("maxplanck.ply", "fcm", "iterative", 0.5): (12722, "e4eb0d3967f3de05"),
    ("maxplanck.ply", "fcm", "coverage", 0.5): (12722, "7ee539819ae14bb7"),
    ("autzen_trim.laz", "km", "threshold", None): (105529, "b35564d5d5e6688a"),
    ("autzen_trim.laz", "km", "iterative", None): (106936, "8fe7d11cc03bd190"),
    ("autzen_trim.laz", "km", "target", 0.5): (55000, "8b39e36136ecc0d2"),
    ("autzen_trim.laz", "km", "iterative", 0.5): (55000, "6a6a3e1227a2b4d1"),
    ("autzen_trim.laz", "km", "coverage", 0.5): (55000, "e0345d3d8e2daeb6"),
    ("autzen_trim.laz", "fcm", "threshold", None): (105718, "5ccb4e53c1600281"),
    ("autzen_trim.laz", "fcm", "iterative", None): (106654, "97d1758e818b31ad"),
    ("autzen_trim.laz", "fcm", "target", 0.5): (55000, "c4f182955a1475f6"),
    ("autzen_trim.laz", "fcm", "iterative", 0.5): (55000, "a4af2aa62da7181d"),
    ("autzen_trim.laz", "fcm", "coverage", 0.5): (55000, "f9dea7c61fe6de25"),
}


@functools.lru_cache(maxsize=None)
def cloud(name: str) -> np.ndarray:
    """The coordinates (n, 3) float64 of a shared scan, read once per session."""
    return read_cloud(shared_file(name))[0]


@pytest.mark.parametrize("name,method,rule,ratio", list(KEPT), ids=["-".join(map(str, k)) for k in KEPT])
def test_kept_set_unchanged(name, method, rule, ratio):
    xyz = cloud(name)
    kw = {} if ratio is None else {"ratio": ratio}
    kept = np.sort(np.asarray(simplify_points(xyz, method=method, rule=rule, seed=0, **kw)))
    digest = hashlib.sha256(kept.astype(np.int64).tobytes()).hexdigest()[:16]
    assert (len(kept), digest) == KEPT[(name, method, rule, ratio)]
