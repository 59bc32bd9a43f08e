"""The VPC's CRS and extents (io/vpc.py, io/vpc_crs.py) on real scans, checked against pyproj and wrench's reader.

Each shared scan carries its CRS differently: autzen_trim.laz a WKT VLR beside
GeoTIFF keys, Megaplot.laz GeoTIFF keys only, simple.copc.laz a compound WKT,
autzen_trim_7.las a WKT VLR alone, simple.laz none.
"""

from __future__ import annotations

import json
import logging

import laspy
import numpy as np
import pyproj
import pytest
from conftest import shared_file

from cloudsieve.errors import InputFormatError
from cloudsieve.io.vpc import describe_tile, read_vpc, read_vpc_items, write_vpc
from cloudsieve.store import ingest
from cloudsieve.store.tiles import export_tiles

#: file -> tile edge in its units (2 to 12 tiles each)
SCANS = {"autzen_trim.laz": 500.0, "Megaplot.laz": 100.0, "simple.copc.laz": 2000.0, "autzen_trim_7.las": 500.0}


def wrench_reads(doc: dict) -> None:
    """What PDAL wrench's ``VirtualPointCloud::read`` (src/vpc.cpp) takes from each item, and STAC's required keys.

    wrench skips an item without type "Feature", stac_version "1.0.0", an
    assets object or a properties object; then reads the first asset's href
    (resolved only when it starts with "./"), ``pc:count``, ``proj:wkt2``,
    ``proj:geometry`` (GeoJSON), ``proj:bbox`` (6 numbers) and ``pc:schemas``
    (name, type, size). STAC items also need id, geometry, bbox, links and
    ``datetime``; the vpc-spec asks for bounds in WGS 84 and recommends 3D.
    """
    assert doc["type"] == "FeatureCollection" and isinstance(doc["features"], list)
    for f in doc["features"]:
        assert f["type"] == "Feature" and f["stac_version"] == "1.0.0"
        assert {"id", "geometry", "bbox", "links", "assets", "properties"} <= set(f)
        assert isinstance(f["assets"], dict) and isinstance(f["properties"], dict)
        assert next(iter(f["assets"].values()))["href"].startswith("./")
        p = f["properties"]
        assert isinstance(p["datetime"], str) and isinstance(p["pc:count"], int)
        assert isinstance(p["proj:wkt2"], str)
        assert p["proj:geometry"]["type"] == "Polygon" and len(p["proj:bbox"]) == 6
        assert all(isinstance(v, float) for v in p["proj:bbox"])
        assert all({"name", "type", "size"} <= set(s) for s in p["pc:schemas"])
        assert len(f["bbox"]) == 6 and f["geometry"]["type"] == "Polygon"


def in_box(lon, lat, bbox) -> bool:
    return bool(np.all((bbox[0] <= lon) & (lon <= bbox[3]) & (bbox[1] <= lat) & (lat <= bbox[4])))


@pytest.mark.parametrize("name", sorted(SCANS))
def test_tiles_vpc_carries_the_crs_and_wgs84_extents(name, tmp_path):
    src = shared_file(name)
    header = laspy.open(str(src)).header
    crs = header.parse_crs()
    store = ingest(str(src), tmp_path / "s.zarr")
    export_tiles(store, tmp_path / "tiles", tile_size=SCANS[name])
    vpc = tmp_path / "tiles" / "index.vpc"
    doc = json.loads(vpc.read_text())
    wrench_reads(doc)
    assert len(doc["features"]) >= 2
    # an independent oracle: the input's own CRS (laspy's reading of its VLRs), its horizontal part to WGS 84
    horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
    to_wgs84 = pyproj.Transformer.from_crs(horizontal, "EPSG:4326", always_xy=True)
    for f in doc["features"]:
        p = f["properties"]
        assert p["proj:wkt2"] and pyproj.CRS.from_user_input(p["proj:wkt2"]) == crs
        tile = laspy.open(str(tmp_path / "tiles" / f["assets"]["data"]["href"][2:])).header
        assert p["proj:bbox"] == [*tile.mins, *tile.maxs]  # native, as the tile's header says
        x0, y0, z0, x1, y1, z1 = p["proj:bbox"]
        assert p["proj:geometry"]["coordinates"] == [[[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]]
        bbox = f["bbox"]
        assert -180 <= bbox[0] <= bbox[3] <= 180 and -90 <= bbox[1] <= bbox[4] <= 90
        assert (bbox[2], bbox[5]) == (z0, z1)  # heights kept, as in the file
        # the bbox holds the reprojected box: corners and points along every edge
        t = np.linspace(0.0, 1.0, 101)
        ex = np.r_[x0 + (x1 - x0) * t, np.full_like(t, x1), x1 - (x1 - x0) * t, np.full_like(t, x0)]
        ey = np.r_[np.full_like(t, y0), y0 + (y1 - y0) * t, np.full_like(t, y1), y1 - (y1 - y0) * t]
        lon, lat = to_wgs84.transform(ex, ey)
        assert in_box(lon, lat, bbox)
        # and tightly: each side within 1e-9 degrees of the reprojected edges' extreme
        np.testing.assert_allclose([bbox[0], bbox[1], bbox[3], bbox[4]],
                                   [lon.min(), lat.min(), lon.max(), lat.max()], rtol=0, atol=1e-9)
        # the geometry: the corners reprojected, counter-clockwise, closed, inside the bbox
        ring = np.array(f["geometry"]["coordinates"][0])
        want = np.c_[to_wgs84.transform([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0])]
        np.testing.assert_allclose(ring, want, rtol=0, atol=1e-12)
        assert in_box(ring[:, 0], ring[:, 1], bbox)
        area = np.sum(ring[:-1, 0] * ring[1:, 1] - ring[1:, 0] * ring[:-1, 1]) / 2
        assert area > 0
    # read back: the same files, their native bounds and CRS, and the same cloud
    items = read_vpc_items(vpc)
    assert [i["path"] for i in items] == read_vpc(vpc)
    assert [i["bounds"] for i in items] == [[f["properties"]["proj:bbox"][:3], f["properties"]["proj:bbox"][3:]]
                                           for f in doc["features"]]
    assert [i["count"] for i in items] == [f["properties"]["pc:count"] for f in doc["features"]]
    assert {i["wkt"] for i in items} == {doc["features"][0]["properties"]["proj:wkt2"]}
    back = ingest(str(vpc), tmp_path / "back.zarr")
    assert back.count == header.point_count
    key = lambda a: a[np.lexsort(a.T[::-1])]  # noqa: E731
    src_points = laspy.read(str(src))
    np.testing.assert_array_equal(key(np.asarray(back.array("xyz")[:])),
                                  key(np.c_[src_points.X, src_points.Y, src_points.Z]))


def test_geotiff_keys_only_give_a_wkt2_and_the_epsg_code():
    mega = describe_tile(shared_file("Megaplot.laz"))
    assert mega["epsg"] == 26917
    assert mega["wkt"].startswith('PROJCRS["NAD83 / UTM zone 17N",')
    assert pyproj.CRS.from_wkt(mega["wkt"]).to_epsg() == 26917
    autzen = describe_tile(shared_file("autzen_trim.laz"))  # WKT VLR and GeoTIFF keys: the WKT VLR's text
    vlr = next(v for v in laspy.open(shared_file("autzen_trim.laz")).header.vlrs
               if type(v).__name__ == "WktCoordinateSystemVlr")
    assert autzen["wkt"] == vlr.string.rstrip("\0") and autzen["epsg"] is None


def test_geotiff_keys_with_a_vertical_crs_give_a_compound_wkt(tmp_path):
    las = laspy.read(str(shared_file("Megaplot.laz")))
    directory = next(v for v in las.header.vlrs if type(v).__name__ == "GeoKeyDirectoryVlr")
    vertical = laspy.vlrs.known.GeoKeyEntryStruct()
    vertical.id, vertical.tiff_tag_location, vertical.count, vertical.value_offset = 4096, 0, 1, 5703
    directory.geo_keys.append(vertical)
    directory.geo_keys_header.number_of_keys += 1
    path = tmp_path / "mega_navd88.laz"
    las.write(str(path))
    entry = describe_tile(path)
    crs = pyproj.CRS.from_wkt(entry["wkt"])
    assert crs.is_compound and [c.to_epsg() for c in crs.sub_crs_list] == [26917, 5703]
    assert crs.name == "NAD83 / UTM zone 17N + NAVD88 height"
    assert entry["epsg"] is None  # a compound CRS has no single code
    write_vpc(tmp_path / "m.vpc", [entry])
    f = json.loads((tmp_path / "m.vpc").read_text())["features"][0]
    assert "proj:epsg" not in f["properties"] and -79 < f["bbox"][0] < f["bbox"][3] < -78


def test_no_crs_or_a_local_frame_keeps_native_extents(tmp_path, caplog):
    simple = describe_tile(shared_file("simple.laz"))
    assert simple["wkt"] is None
    write_vpc(tmp_path / "s.vpc", [simple])
    f = json.loads((tmp_path / "s.vpc").read_text())["features"][0]
    assert f["properties"]["proj:wkt2"] == ""  # wrench's "no CRS"
    assert f["bbox"] == f["properties"]["proj:bbox"] == [*simple["bounds"][0], *simple["bounds"][1]]
    assert f["geometry"] == f["properties"]["proj:geometry"]
    local = dict(simple, wkt='LOCAL_CS["site grid",UNIT["metre",1]]')
    with caplog.at_level(logging.WARNING, logger="cloudsieve.io.vpc"):
        write_vpc(tmp_path / "l.vpc", [local, dict(local, path=str(shared_file("simple.las")))])
    f = json.loads((tmp_path / "l.vpc").read_text())["features"][0]
    assert f["bbox"] == f["properties"]["proj:bbox"] and f["properties"]["proj:wkt2"] == local["wkt"]
    assert [r.getMessage() for r in caplog.records] == [
        f'{tmp_path / "l.vpc"}: the CRS LOCAL_CS["site grid",UNIT["metre",1]]... does not reproject to WGS 84 '
        f"(Error creating Transformer from CRS.): bbox and geometry are in the files' own coordinates"]


def test_read_vpc_items_native_bounds_of_every_layout(tmp_path):
    tile = shared_file("simple.laz")
    native, wgs84 = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0], [-123.1, 44.0, 3.0, -123.0, 44.1, 6.0]

    def item(props=None, **f):
        return {"type": "Feature", "id": "t", "properties": props or {},
                "assets": {"data": {"href": str(tile), "roles": ["data"]}}, **f}

    def read(*features):
        (tmp_path / "v.vpc").write_text(json.dumps({"type": "FeatureCollection", "features": list(features)}))
        return read_vpc_items(tmp_path / "v.vpc")

    # proj:bbox first (wrench, QGIS, cloudsieve); the bbox of an item without CRS; none from a WGS 84 bbox alone
    [a] = read(item({"proj:bbox": native, "proj:wkt2": "EPSG:2992", "pc:count": 7}, bbox=wgs84))
    assert a == {"path": str(tile), "count": 7, "wkt": "EPSG:2992", "bounds": [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]}
    [b] = read(item({"proj:wkt2": ""}, bbox=native))
    assert b["bounds"] == [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]] and b["wkt"] is None and b["count"] is None
    [c] = read(item({"proj:epsg": 2992}, bbox=wgs84))
    assert c["bounds"] is None and c["wkt"] == "EPSG:2992"
    [d] = read(item({"proj:bbox": [1, 2, 4, 5]}))
    assert d["bounds"] == [[1.0, 2.0, None], [4.0, 5.0, None]]
    [e] = read(item())  # no properties at all: the file alone
    assert e == {"path": str(tile), "count": None, "wkt": None, "bounds": None}
    with pytest.raises(InputFormatError, match=rf'^{tmp_path}/v.vpc: feature 0 \(\'t\'\): its "proj:bbox" is not 4 '
                                               r'or 6 finite numbers: \[1, 2, 3\]$'):
        read(item({"proj:bbox": [1, 2, 3]}))
