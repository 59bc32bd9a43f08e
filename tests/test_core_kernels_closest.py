"""The label pass's nearest centres (core/kernels/closest.py) against brute force and cKDTree."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from cloudsieve.core.kernels.closest import nearest_sites, site_tree


def brute(sites, points, k):
    """The k smallest (squared distance, index) of every point, distances summed as cKDTree sums them."""
    d2 = ((points[:, None, 0] - sites[None, :, 0]) ** 2 + (points[:, None, 1] - sites[None, :, 1]) ** 2) \
        + (points[:, None, 2] - sites[None, :, 2]) ** 2
    idx = np.array([sorted(range(len(sites)), key=lambda j: (row[j], j))[:k] for row in d2.tolist()], dtype=np.int64)
    return np.sqrt(np.take_along_axis(d2, idx, axis=1)), idx


@pytest.mark.parametrize("seed", range(6))
def test_nearest_sites_equal_brute_force_with_ties_and_copies(seed):
    rng = np.random.default_rng(seed)
    m = int(rng.integers(1, 90))
    # a coarse lattice: many equal distances, copies among the sites, points on the sites; 0.1 makes squared
    # distances that differ in the last bit but share a square root
    sites = rng.integers(0, 4, (m, 3)) * [1.0, 0.5, 0.1][seed % 3]
    points = np.r_[rng.integers(0, 4, (150, 3)) * 0.5, sites[:5]]
    for k in sorted({1, 2, min(6, m), m}):
        d, i = nearest_sites(site_tree(sites), points, k)
        bd, bi = brute(sites, points, k)
        np.testing.assert_array_equal(i, bi)
        np.testing.assert_array_equal(d, bd)


def test_nearest_sites_distances_equal_ckdtree_bit_for_bit():
    rng = np.random.default_rng(3)
    sites = rng.random((300, 3)) * [500.0, 400.0, 30.0] + [4.0e5, 5.0e6, 100.0]
    points = rng.random((20_000, 3)) * [520.0, 420.0, 40.0] + [4.0e5 - 10, 5.0e6 - 10, 95.0]
    d, i = nearest_sites(site_tree(sites), points, 6)
    cd, ci = cKDTree(sites).query(points, k=6)
    np.testing.assert_array_equal(d, cd)
    np.testing.assert_array_equal(i, ci)  # no ties among random distances
