"""The CRS and the WGS 84 footprint of a VPC item, through pyproj.

A VPC item carries ``proj:wkt2`` and its extent in the file's coordinates
(``proj:bbox``/``proj:geometry``) and in WGS 84 (``bbox``/``geometry``), as
STAC requires and wrench writes. :func:`geotiff_wkt`: the WKT of a CRS
given by GeoTIFF keys alone; :func:`wgs84_extent`: the WGS 84 bbox and
polygon of a native box.
"""

from __future__ import annotations

import functools
import logging
import math

__all__ = ["geotiff_wkt", "wgs84_extent", "DENSIFY"]

logger = logging.getLogger(__name__)

#: points per edge of the box reprojected for the WGS 84 bbox (the bbox holds the whole curved footprint)
DENSIFY = 21
#: GeoTIFF keys: ProjectedCSTypeGeoKey, GeographicTypeGeoKey, VerticalCSTypeGeoKey
_PROJECTED, _GEOGRAPHIC, _VERTICAL = 3072, 2048, 4096


def _code(keys: dict, key_id: int) -> int | None:
    """The EPSG code a GeoTIFF key holds directly (1024-32766), else None (absent or user-defined)."""
    key = keys.get(key_id)
    if key is None or key.tiff_tag_location != 0 or not 1024 <= key.value_offset <= 32766:
        return None
    return int(key.value_offset)


def geotiff_wkt(path: str) -> tuple[str | None, int | None]:
    """The CRS of the LAS/LAZ/COPC file *path*'s GeoTIFF keys, as (WKT2 2019, its EPSG code).
    A projected (else geographic) code plus a vertical one make a compound CRS, with EPSG code None. (None, None)
    without keys, without a code, or for a code pyproj does not know."""
    from .las_layout import read_header

    header = read_header(path)
    vlrs = list(header.vlrs) + list(header.evlrs or [])
    directory = next((v for v in vlrs if type(v).__name__ == "GeoKeyDirectoryVlr"), None)
    if directory is None:
        return None, None
    keys = {k.id: k for k in directory.geo_keys}
    horizontal = _code(keys, _PROJECTED) or _code(keys, _GEOGRAPHIC)
    if horizontal is None:
        return None, None
    import pyproj

    vertical = _code(keys, _VERTICAL)
    try:
        crs = pyproj.CRS.from_epsg(horizontal)
        if vertical is not None:
            v = pyproj.CRS.from_epsg(vertical)
            crs = pyproj.crs.CompoundCRS(name=f"{crs.name} + {v.name}", components=[crs, v])
    except pyproj.exceptions.CRSError as exc:
        logger.warning("%s: the GeoTIFF keys name EPSG:%s%s, which pyproj does not know (%s)", path, horizontal,
                       f" + EPSG:{vertical}" if vertical else "", exc)
        return None, None
    return crs.to_wkt("WKT2_2019"), (horizontal if vertical is None else None)


@functools.lru_cache(maxsize=32)
def _to_wgs84(wkt: str):
    """A transformer from *wkt*'s horizontal CRS to WGS 84 longitude/latitude, or the reason there is none."""
    import pyproj

    try:
        crs = pyproj.CRS.from_user_input(wkt)
        horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
        return pyproj.Transformer.from_crs(horizontal, "EPSG:4326", always_xy=True)
    except pyproj.exceptions.ProjError as exc:  # CRSError among them
        return str(exc)


def wgs84_extent(wkt: str, lo: list[float], hi: list[float]) -> tuple[list[float], dict]:
    """The WGS 84 ``bbox`` and ``geometry`` of the native box [*lo*, *hi*] in the CRS *wkt*.
    The bbox ``[lon_min, lat_min, z_min, lon_max, lat_max, z_max]`` bounds the box's densified edges (heights as in
    the file); the geometry is a counter-clockwise GeoJSON Polygon of the corners. ValueError (saying why) when
    *wkt* does not reproject to WGS 84 here."""
    transformer = _to_wgs84(wkt)
    if isinstance(transformer, str):
        raise ValueError(transformer)
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    import pyproj

    try:
        w, s, e, n = transformer.transform_bounds(x0, y0, x1, y1, densify_pts=DENSIFY)
        lons, lats = transformer.transform([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], errcheck=True)
    except pyproj.exceptions.ProjError as exc:
        raise ValueError(f"the box {lo}..{hi} does not reproject: {exc}") from None
    values = [w, s, e, n, *lons, *lats]
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"the box {lo}..{hi} is outside the CRS's area (infinite longitudes or latitudes)")
    ring = [[float(a), float(b)] for a, b in zip(lons, lats)]
    return [float(w), float(s), float(z0), float(e), float(n), float(z1)], {"type": "Polygon", "coordinates": [ring]}
