"""Compiled helpers of the elimination's coverage term, kept current on every removal (numba; private).

Each point p has a "rep" (itself while it remains, else its nearest remaining
point); ``alt[p]``/``altd2[p]`` is the nearest remaining point other than the rep
(-1 / inf: none). Found by resuming a scan of p's sorted list (``soff`` of
:mod:`.neighbours`) at ``sp[p]`` (points only go, so the scan only moves forward),
past it by :func:`.grid.nearest`. Points with alt a form a doubly linked list
(``ahead``/``anext``/``aprev``). Per rep, ``c2b``/``cerr``, ``e2b``, ``nmem``,
``nmiss`` give an upper bound of the coverage factor (:func:`fbound`).
"""

from __future__ import annotations

from numba import njit

from .grid import nearest


@njit(cache=True)
def next_alt(p, x, start, P, cell, cstart, nstart, ncells, state, tie, nptr, nbr, soff):
    """Nearest remaining point to p other than x from position ``start`` of p's sorted list: (point, squared distance, position)."""
    end = nptr[p + 1]
    s = nptr[p]
    for t in range(start, end):
        j = nbr[s + soff[t]]
        if j != x and state[j] != 0:
            dx = P[j, 0] - P[p, 0]
            dy = P[j, 1] - P[p, 1]
            dz = P[j, 2] - P[p, 2]
            return j, dx * dx + dy * dy + dz * dz, t
    a, d2 = nearest(p, x, P, cell, cstart, nstart, ncells, state, tie)
    return a, d2, end


@njit(cache=True)
def link(p, a, ahead, anext, aprev):
    """Put p in the list of points whose alt is a."""
    h = ahead[a]
    anext[p] = h
    aprev[p] = -1
    if h >= 0:
        aprev[h] = p
    ahead[a] = p


@njit(cache=True)
def unlink(p, a, ahead, anext, aprev):
    """Take p out of the list of points whose alt is a."""
    if aprev[p] >= 0:
        anext[aprev[p]] = anext[p]
    else:
        ahead[a] = anext[p]
    if anext[p] >= 0:
        aprev[anext[p]] = aprev[p]


@njit(cache=True)
def gain(p, x, d2, P):
    """Squared distance p would gain if its rep x went and it moved to the point at squared distance d2."""
    dx = P[p, 0] - P[x, 0]
    dy = P[p, 1] - P[x, 1]
    dz = P[p, 2] - P[x, 2]
    return d2 - (dx * dx + dy * dy + dz * dz)


@njit(cache=True)
def add_gain(x, t, c2b, cerr):
    """c2b[x] += t, with the rounding bound."""
    c2b[x] += t
    cerr[x] += 2.0**-51 * (abs(c2b[x]) + abs(t))


@njit(cache=True)
def fbound(x, e2b, c2b, cerr, nmem, nmiss, imp2, rc2, gamma, lam, inv_r2):
    """An upper bound of the coverage factor f(x) (exact e, c lowered below every rounding of its sum)."""
    if nmiss[x] > 0:
        return 0.0
    e2 = e2b[x] * max(imp2[x], 1.0)
    c2 = max(0.0, (c2b[x] - 2.0 * cerr[x]) * (1.0 - (nmem[x] + 4) * 2.0**-52)) * imp2[x]
    f = 1.0
    if rc2 > 0 and e2 > rc2:
        f = falloff(rc2 / e2, gamma)
    return f / (1.0 + lam * c2 * inv_r2)


@njit(cache=True, inline="always")
def falloff(t, gamma):
    """t ** (gamma / 2) for t < 1: two squarings for gamma = 8, else pow; monotone either way."""
    if gamma == 8.0:
        t *= t
        return t * t
    return t ** (0.5 * gamma)


@njit(cache=True)
def resume_at(p, sp, nptr):
    """Where the next search of p's alt starts: after the last one found, unless past p's list."""
    return sp[p] + 1 if sp[p] < nptr[p + 1] else sp[p]


@njit(cache=True)
def take_alt(p, x, start, P, cell, cstart, nstart, ncells, state, tie, nptr, nbr, soff, alt, altd2, sp, ahead,
             anext, aprev, e2b, c2b, cerr, nmiss):
    """Give p (represented by x) its next alt from ``start`` of its list, and add it to x's coverage data."""
    b, d2, sp[p] = next_alt(p, x, start, P, cell, cstart, nstart, ncells, state, tie, nptr, nbr, soff)
    alt[p] = b
    altd2[p] = d2
    if b >= 0:
        link(p, b, ahead, anext, aprev)
        e2b[x] = max(e2b[x], d2)
        add_gain(x, gain(p, x, d2, P), c2b, cerr)
    else:
        nmiss[x] += 1.0
