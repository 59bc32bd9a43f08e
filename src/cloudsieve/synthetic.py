"""A built-in example scan: terrain, buildings and trees with LAS attributes (``cloudsieve demo``, benchmarks).

Generated block by block from one seed: any size, bounded memory, same seed same points.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from .store import DEFAULT_CHUNK_SIZE

__all__ = ["scene_chunks", "write_scene_laz"]

# Scene extent in metres; points are spread over it whatever the count.
_EXTENT = 400.0


def _ground(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 2.0 * np.sin(x / 37.0) + 1.5 * np.cos(y / 23.0) + 0.01 * x


def _buildings(rng: np.random.Generator) -> np.ndarray:
    """(b, 5) rows of centre x, centre y, half width, half depth, height."""
    b = 12
    centres = rng.uniform(40, _EXTENT - 40, size=(b, 2))
    half = rng.uniform(6, 15, size=(b, 2))
    height = rng.uniform(6, 25, size=(b, 1))
    return np.hstack([centres, half, height])


def scene_chunks(n: int, *, seed: int = 0, chunk_size: int = DEFAULT_CHUNK_SIZE) -> Iterator[dict[str, np.ndarray]]:
    """Yield the example scene of *n* points (layout and chunks from *seed*) in chunks of at most *chunk_size*.
    Each chunk: ``xyz`` (m, 3) float64 and laspy-named attributes: ``intensity`` (uint16), ``classification``
    (uint8; 2 ground, 5 high vegetation, 6 building), ``gps_time`` (float64),
    ``return_number``/``number_of_returns`` (uint8), ``red``/``green``/``blue`` (uint16)."""
    root = np.random.SeedSequence(seed)
    layout_seq, *_ = root.spawn(1)
    buildings = _buildings(np.random.default_rng(layout_seq))
    n_chunks = max(1, -(-n // chunk_size))
    for i, seq in enumerate(np.random.SeedSequence([seed, 1]).spawn(n_chunks)):
        m = min(chunk_size, n - i * chunk_size)
        rng = np.random.default_rng(seq)
        x = rng.uniform(0, _EXTENT, m)
        y = rng.uniform(0, _EXTENT, m)
        z = _ground(x, y) + rng.normal(0, 0.03, m)
        cls = np.full(m, 2, np.uint8)
        # Building roofs (flat, with a little noise) over their footprints.
        for cx, cy, hx, hy, h in buildings:
            inside = (np.abs(x - cx) < hx) & (np.abs(y - cy) < hy)
            z[inside] = _ground(cx, cy) + h + rng.normal(0, 0.02, inside.sum())
            cls[inside] = 6
        # Tree crowns: a fifth of the ground points lifted into ellipsoidal canopies.
        trees = (cls == 2) & (rng.random(m) < 0.2)
        crown = 4.0 + 6.0 * np.abs(np.sin(x[trees] / 7.0) * np.cos(y[trees] / 5.0))
        z[trees] += crown * rng.uniform(0.3, 1.0, trees.sum())
        cls[trees] = 5
        returns = np.where(trees, rng.integers(1, 4, m), 1).astype(np.uint8)
        intensity = np.where(cls == 6, 1800, np.where(cls == 5, 700, 1200)) + rng.integers(0, 300, m)
        red = np.where(cls == 5, 60, np.where(cls == 6, 180, 140)) * 256
        green = np.where(cls == 5, 140, np.where(cls == 6, 170, 120)) * 256
        blue = np.where(cls == 5, 50, np.where(cls == 6, 160, 90)) * 256
        yield {
            "xyz": np.column_stack([x, y, z]),
            "intensity": intensity.astype(np.uint16),
            "classification": cls,
            "gps_time": 1.0e8 + (i * chunk_size + np.arange(m)) * 1e-5,
            "return_number": np.minimum(returns, 1 + (rng.random(m) < 0.3)).astype(np.uint8),
            "number_of_returns": returns,
            "red": red.astype(np.uint16),
            "green": green.astype(np.uint16),
            "blue": blue.astype(np.uint16),
        }


def write_scene_laz(path: str, n: int, *, seed: int = 0, chunk_size: int = DEFAULT_CHUNK_SIZE) -> str:
    """Write the example scene as a LAS 1.4 point format 7 file (LAZ by ``.laz``), atomically; returns *path*."""
    import laspy

    from .atomic import replacing

    header = laspy.LasHeader(point_format=7, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([0.0, 0.0, -10.0])
    header.generating_software = "cloudsieve synthetic scene"
    with replacing(path) as tmp:  # the umask's mode, as every output
        with laspy.open(tmp, mode="w", header=header, do_compress=path.lower().endswith(".laz")) as writer:
            for chunk in scene_chunks(n, seed=seed, chunk_size=chunk_size):
                record = laspy.ScaleAwarePointRecord.zeros(len(chunk["xyz"]), header=header)
                record.x, record.y, record.z = chunk["xyz"].T
                for name, values in chunk.items():
                    if name != "xyz":
                        record[name] = values
                writer.write_points(record)
    return path
