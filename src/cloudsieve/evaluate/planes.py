"""Point-to-plane (D2) errors, the original's normals, and the field's figures: D1/D2 PSNR and Chamfer.

The figures MPEG's ``pc_error`` (mpeg-pcc-dmetric) reports, with A = the
original and B = the simplified cloud:

- **D1** (point-to-point): the squared distance from a point to its nearest
  neighbour in the other cloud;
- **D2** (point-to-plane): the error vector of the same pair projected on the
  original's normal, squared: ``((b - a) . n_a)**2`` where ``a`` is the pair's
  original point (forward A -> B: the query point itself; backward B -> A:
  the nearest original point of ``b``). ``pc_error`` projects the forward
  pairs on a normal moved from A to the matched point of B (the average of the
  normals of the original points whose nearest neighbour it is); on a smooth
  surface both are the same plane, and using ``n_a`` keeps the computation to
  one streamed pass;
- the **MSE** of each direction (mean over the points of the direction's
  cloud), the **symmetric** MSE the larger of the two, and
  ``PSNR = 10 log10(3 p**2 / MSE)`` dB with a stated peak ``p`` (default: the
  original's bounding-box diagonal). An MSE of 0 (e.g. backward, when B is a
  subset of A) gives an infinite PSNR (``null`` in report.json).
- **Chamfer distance**: the mean squared nearest-neighbour distance A -> B
  plus the mean squared nearest-neighbour distance B -> A, i.e. the sum of the
  two D1 MSEs, in squared cloud units.

Normals come from the file when it has ``nx, ny, nz``; otherwise each is
estimated by PCA of the point's ``K_NORMALS`` nearest neighbours (the
eigenvector of the smallest eigenvalue of their covariance). The original is
streamed, so the neighbours are searched within the point's chunk of the
original (``chunk_size`` points, 1 M by default): exact for a cloud of one
chunk; at the edge of a chunk the neighbourhood may be one-sided.
Normals are only computed where the D1 error is not zero (a zero error has a
zero projection).

On a large cloud the normals dominate the point level's time (a k-NN query
and a 3x3 eigenproblem per dropped point: 3-6 times the D1 pass), so D2 is
measured on a uniform seeded sample of at most ``d2_sample`` points per
direction (:func:`cloudsieve.evaluate.points.point_errors`), every point of
a smaller cloud: the MSE is the sample's mean squared projection, its
standard error stated (``d2_se``; in dB, 10/ln 10 x se/MSE). D1 and the
Chamfer distance stay exact.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from .morton import morton_order

__all__ = ["K_NORMALS", "D2_SAMPLE", "pca_normals", "unit_normals", "d2_squares", "backward_chunk", "psnr", "field_figures"]

#: neighbours of the PCA normal estimate (the point itself included)
K_NORMALS = 12
#: D2 on a uniform sample of at most this many points per direction (``d2_sample``, params.py's default)
D2_SAMPLE = 1_000_000
#: normals estimated per block of points (bounds the (block, k, 3) memory)
_BLOCK = 65_536


@njit(cache=True, nogil=True)
def _smallest_eigenvector(a: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Unit eigenvector of the smallest eigenvalue of the symmetric 3x3 *a* (cyclic Jacobi; *a* is overwritten)."""
    v = np.eye(3)
    for _ in range(32):
        off = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
        diag = a[0, 0] * a[0, 0] + a[1, 1] * a[1, 1] + a[2, 2] * a[2, 2]
        if off <= 1e-30 * diag or off == 0.0:
            break
        for pq in range(3):
            p = 0 if pq < 2 else 1
            q = 1 if pq == 0 else 2
            if a[p, q] == 0.0:
                continue
            theta = (a[q, q] - a[p, p]) / (2.0 * a[p, q])
            t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
            if theta < 0.0:
                t = -t
            c = 1.0 / math.sqrt(t * t + 1.0)
            s = t * c
            for k in range(3):
                akp, akq = a[k, p], a[k, q]
                a[k, p] = c * akp - s * akq
                a[k, q] = s * akp + c * akq
            for k in range(3):
                apk, aqk = a[p, k], a[q, k]
                a[p, k] = c * apk - s * aqk
                a[q, k] = s * apk + c * aqk
            for k in range(3):
                vkp, vkq = v[k, p], v[k, q]
                v[k, p] = c * vkp - s * vkq
                v[k, q] = s * vkp + c * vkq
    j = 0
    if a[1, 1] < a[j, j]:
        j = 1
    if a[2, 2] < a[j, j]:
        j = 2
    return v[:, j].copy()


@njit(cache=True, nogil=True)
def _normals_kernel(points: np.ndarray, nb: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """``out[i]``: PCA normal of the points ``points[nb[i]]`` (rows of *nb* are neighbour indices)."""
    k = nb.shape[1]
    cov = np.empty((3, 3))
    for i in range(nb.shape[0]):
        m0 = m1 = m2 = 0.0
        for j in range(k):
            r = nb[i, j]
            m0 += points[r, 0]
            m1 += points[r, 1]
            m2 += points[r, 2]
        m0 /= k
        m1 /= k
        m2 /= k
        cov[:, :] = 0.0
        for j in range(k):
            r = nb[i, j]
            x, y, z = points[r, 0] - m0, points[r, 1] - m1, points[r, 2] - m2
            cov[0, 0] += x * x
            cov[0, 1] += x * y
            cov[0, 2] += x * z
            cov[1, 1] += y * y
            cov[1, 2] += y * z
            cov[2, 2] += z * z
        cov[1, 0], cov[2, 0], cov[2, 1] = cov[0, 1], cov[0, 2], cov[1, 2]
        out[i] = _smallest_eigenvector(cov)


def pca_normals(points: np.ndarray, centres: np.ndarray, k: int = K_NORMALS, tree: cKDTree | None = None) -> np.ndarray:
    """Unit normals at *centres* by PCA of their *k* nearest neighbours among *points*.

    Parameters
    ----------
    points : ndarray of shape (n, 3), float64
        Where the neighbours are searched.
    centres : ndarray of shape (c, 3), float64
        Where the normals are wanted (usually rows of *points*: the point
        itself is then one of its k neighbours).
    k : int
        Neighbours (at most n are used; with fewer than 3, the normals are 0
        and every projection on them is 0).
    tree : cKDTree, optional
        A tree over *points*, when one is at hand.

    Returns
    -------
    ndarray of shape (c, 3), float64
        Unit normals, of arbitrary sign.
    """
    k = min(int(k), len(points))
    out = np.zeros((len(centres), 3))
    if k < 3 or len(centres) == 0:
        return out
    if tree is None:
        tree = cKDTree(points, balanced_tree=False, compact_nodes=False)
    pts = np.ascontiguousarray(points, dtype=np.float64)
    order = morton_order(centres)  # cache-friendly queries: about 3 times faster than in file order
    for s in range(0, len(centres), _BLOCK):
        rows = order[s : s + _BLOCK]
        _, nb = tree.query(centres[rows], k=k, workers=-1)
        block = np.empty((len(rows), 3))
        _normals_kernel(pts, np.ascontiguousarray(nb, dtype=np.int64), block)
        out[rows] = block
    return out


def unit_normals(normals: np.ndarray) -> np.ndarray:
    """*normals* (n, 3) scaled to unit length (zero rows stay 0)."""
    n = np.asarray(normals, dtype=np.float64)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


def d2_squares(xyz: np.ndarray, rows: np.ndarray, errors: np.ndarray, normals: np.ndarray | None = None,
               k: int = K_NORMALS, tree: cKDTree | None = None) -> np.ndarray:
    """Squared projections of *errors* on the original's normals at ``xyz[rows]`` (a chunk kernel).

    Parameters
    ----------
    xyz : ndarray of shape (n, 3), float64
        A chunk of the original (the normals' neighbourhoods).
    rows : ndarray of shape (r,), int
        The original points whose errors are given.
    errors : ndarray of shape (r, 3), float64
        Error vectors (other point minus original point).
    normals : ndarray of shape (n, 3), optional
        The chunk's normals from the file; estimated (PCA, *k*) when None.

    Returns
    -------
    ndarray of shape (r,), float64
    """
    if len(rows) == 0:
        return np.zeros(0)
    n = unit_normals(normals[rows]) if normals is not None else pca_normals(xyz, xyz[rows], k, tree)
    proj = np.einsum("ij,ij->i", errors, n)
    return proj * proj


def backward_chunk(xyz: np.ndarray, points: np.ndarray, best: np.ndarray, *, normals: np.ndarray | None = None,
                   k: int | None = K_NORMALS, d2_mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Distances from *points* (u, 3) to one chunk of original points, where they can beat *best*.

    Parameters
    ----------
    xyz : ndarray of shape (n, 3), float64
        One chunk of the original.
    points : ndarray of shape (u, 3), float64
        The simplified points searched.
    best : ndarray of shape (u,)
        The best distances so far (chunks farther, by bounding box, are skipped).
    normals : ndarray of shape (n, 3), optional
        The chunk's normals from the file (else estimated, *k* neighbours).
    k : int or None
        Neighbours of the normal estimate; None: no D2.
    d2_mask : ndarray of shape (u,), bool, optional
        The points of the D2 sample (default: all); *d2* is 0 for the others.

    Returns
    -------
    d : ndarray of shape (u,)
        Distances, ``inf`` where the chunk cannot beat *best*.
    d2 : ndarray of shape (u,)
        Squared projection of each error on the original's normal at the
        nearest point of the chunk (0 where *d* is inf or 0, or without D2).
        Combine chunks by keeping, per point, the pair of the smaller *d*.
    """
    out, out2 = np.full(len(points), np.inf), np.zeros(len(points))
    if len(xyz) == 0 or len(points) == 0:
        return out, out2
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    gap = np.linalg.norm(np.maximum(np.maximum(lo - points, points - hi), 0.0), axis=1)
    todo = np.flatnonzero(gap < best)
    if len(todo):
        tree = cKDTree(xyz, balanced_tree=False, compact_nodes=False)
        sub = todo[morton_order(points[todo])]
        d, j = tree.query(points[sub], k=1, workers=-1)
        out[sub] = d
        if k is not None:
            win = (d < best[sub]) & (d > 0)  # pairs that can win, with an error to project
            w = np.flatnonzero(win if d2_mask is None else win & d2_mask[sub])
            if len(w):
                rows = j[w]
                out2[sub[w]] = d2_squares(xyz, rows, points[sub[w]] - xyz[rows], normals, k, tree)
    return out, out2


def psnr(mse: float, peak: float) -> float:
    """``10 log10(3 peak**2 / mse)`` dB; inf when *mse* is 0."""
    if mse <= 0:
        return math.inf
    return 10.0 * math.log10(3.0 * peak * peak / mse)


def field_figures(forward: dict, backward: dict, *, diagonal: float, peak: float | None = None,
                  normals: str = "estimated", k: int = K_NORMALS) -> tuple[dict, dict]:
    """``report["psnr"]`` and ``report["chamfer"]`` from the point level's two directions.

    Parameters
    ----------
    forward, backward : dict
        :func:`.distances.aggregate` results holding ``mse`` and ``d2_mse``.
    diagonal : float
        The original's bounding-box diagonal (the default peak).
    peak : float, optional
        The PSNR peak p.
    normals : str
        ``"file"`` or ``"estimated"``: where the original's normals came from.
    k : int
        Neighbours of the estimate.

    Returns
    -------
    psnr : dict
        ``peak``, ``peak_from`` ("diagonal" or "given"), ``formula``,
        ``normals``, ``k_normals`` (None with file normals), ``d1`` and ``d2``
        (``forward``, ``backward``, ``symmetric`` in dB), ``mse`` (the same
        three per metric, squared cloud units); when D2 was measured on a
        sample, ``d2_sample`` (``forward``/``backward``: its size, None for
        every point) and ``d2_se_db`` (the standard error of each D2 PSNR
        in dB, 10/ln 10 x se/MSE; 0 for an exact one).
    chamfer : dict
        ``value`` (= ``forward`` + ``backward``), ``forward``, ``backward``
        (mean squared nearest-neighbour distances, squared cloud units),
        ``value_pct2`` (value in % of the diagonal, squared: 100**2 value /
        diagonal**2) and ``definition``.
    """
    p = float(diagonal if peak is None else peak)
    mse, out = {}, {}
    for name, key in (("d1", "mse"), ("d2", "d2_mse")):
        f, b = float(forward[key]), float(backward[key])
        mse[name] = {"forward": f, "backward": b, "symmetric": max(f, b)}
        out[name] = {d: psnr(v, p) for d, v in mse[name].items()}
    figures = {"peak": p, "peak_from": "diagonal" if peak is None else "given",
               "formula": "10*log10(3*peak^2/MSE) dB", "normals": normals,
               "k_normals": None if normals == "file" else int(k), **out, "mse": mse}
    if "d2_sample" in forward or "d2_sample" in backward:
        figures["d2_sample"] = {name: d.get("d2_sample") for name, d in (("forward", forward), ("backward", backward))}
        figures["d2_se_db"] = {name: (10.0 / math.log(10.0)) * d.get("d2_se", 0.0) / d["d2_mse"] if d["d2_mse"] > 0
                               else 0.0 for name, d in (("forward", forward), ("backward", backward))}
    f, b = mse["d1"]["forward"], mse["d1"]["backward"]
    chamfer = {"value": f + b, "forward": f, "backward": b,
               "value_pct2": (f + b) * 1e4 / diagonal**2 if diagonal > 0 else math.nan,
               "definition": "mean squared nearest-neighbour distance original -> simplified plus mean squared "
                             "nearest-neighbour distance simplified -> original (squared cloud units)"}
    return figures, chamfer
