"""The COPC hierarchy: the nodes' 32-byte entries (``(depth, x, y, z)`` int32, chunk offset uint64, byte
size and point count int32; count -1 points to a child page), in pages cut as EPT's "hierarchy step": one
page up to :data:`ROOT_PAGE_NODES` nodes, else a page per node at a depth multiple of
:data:`HIERARCHY_STEP`. The pages follow from the nodes alone, whatever the split into tasks.
"""

from __future__ import annotations

import numpy as np

from .octree import demorton, morton

__all__ = ["ENTRY_DTYPE", "HIERARCHY_STEP", "ROOT_PAGE_NODES", "hierarchy_pages"]

ENTRY_DTYPE = np.dtype([("d", "<i4"), ("x", "<i4"), ("y", "<i4"), ("z", "<i4"), ("offset", "<u8"),
                        ("nbytes", "<i4"), ("count", "<i4")])
#: pages start at the depths that are multiples of this
HIERARCHY_STEP = 4
#: at most this many nodes: a single page
ROOT_PAGE_NODES = 1024


def hierarchy_pages(entries: np.ndarray, at: int, *, step: int = HIERARCHY_STEP,
                    root_nodes: int = ROOT_PAGE_NODES) -> tuple[bytes, int]:
    """The hierarchy's pages, root page first, for file offset *at*: (bytes, root page size).

    *entries*: every node's entry, ENTRY_DTYPE (every ancestor of a node is a
    node); page roots at depths multiple of *step*; at most *root_nodes*
    nodes make a single page.
    """
    entries = np.asarray(entries, dtype=ENTRY_DTYPE)
    if len(entries) <= root_nodes:
        return entries.tobytes(), entries.nbytes
    d = entries["d"].astype(np.int64)
    key = morton(np.stack([entries["x"], entries["y"], entries["z"]], axis=1))
    pd = (d // step) * step
    pkey = key >> (3 * (d - pd))
    # the pages below the root by (depth, key); each node's page (0: root)
    page_depths, page_keys = [], []
    node_page = np.zeros(len(entries), dtype=np.int64)
    for depth in np.unique(pd[pd > 0]):
        at_depth = pd == depth
        uniq, inv = np.unique(pkey[at_depth], return_inverse=True)
        node_page[at_depth] = 1 + sum(len(k) for k in page_keys) + inv
        page_depths.append(np.full(len(uniq), depth))
        page_keys.append(uniq)
    pdepth = np.concatenate(page_depths)
    pkeys = np.concatenate(page_keys)
    n_pages = 1 + len(pkeys)
    # a page's pointer goes in the page one step up
    parent = np.zeros(len(pkeys), dtype=np.int64)
    for depth in np.unique(pdepth):
        if depth == step:
            continue
        here = np.flatnonzero(pdepth == depth)
        up = np.flatnonzero(pdepth == depth - step)
        parent[here] = 1 + up[np.searchsorted(pkeys[up], pkeys[here] >> (3 * step))]
    pointers = np.zeros(len(pkeys), dtype=ENTRY_DTYPE)
    cells = demorton(pkeys)
    pointers["d"], pointers["count"] = pdepth, -1
    pointers["x"], pointers["y"], pointers["z"] = cells[:, 0], cells[:, 1], cells[:, 2]
    rows = np.concatenate([entries, pointers])
    row_page = np.concatenate([node_page, parent])
    sizes = np.bincount(row_page, minlength=n_pages) * ENTRY_DTYPE.itemsize
    offsets = at + np.concatenate([[0], np.cumsum(sizes)[:-1]])
    rows["offset"][len(entries):] = offsets[1:]
    rows["nbytes"][len(entries):] = sizes[1:]
    order = np.argsort(row_page, kind="stable")
    return rows[order].tobytes(), int(sizes[0])
