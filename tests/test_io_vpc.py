"""Virtual point clouds (io/vpc.py): wrench's layout written, read back, and the exact errors."""

from __future__ import annotations

import json
import os

import laspy
import numpy as np
import pytest
from conftest import shared_file
from tiles_data import cut_tiles

from cloudsieve.errors import (
    DestinationExistsError,
    EmptyInputError,
    InputFormatError,
    InputNotFoundError,
    InvalidParameterError,
)
from cloudsieve.io.vpc import STAC_EXTENSIONS, _datetime, describe_tile, read_vpc, write_vpc


@pytest.fixture
def tiles(tmp_path):
    """autzen_trim.laz cut into 4 real LAZ tiles."""
    return cut_tiles(shared_file("autzen_trim.laz"), tmp_path / "tiles")


def source_wkt() -> str:
    las = laspy.open(shared_file("autzen_trim.laz"))
    vlr = next(v for v in las.header.vlrs if type(v).__name__ == "WktCoordinateSystemVlr")
    return vlr.string.rstrip("\0")


def test_write_read_round_trip_in_wrench_layout(tiles, tmp_path):
    vpc = tmp_path / "tiles" / "index.vpc"
    assert write_vpc(vpc, [describe_tile(p) for p in tiles]) == str(vpc)
    assert read_vpc(vpc) == [str(p) for p in tiles]
    doc = json.loads(vpc.read_text())
    assert list(doc) == ["type", "features"] and doc["type"] == "FeatureCollection"
    assert len(doc["features"]) == 4
    wkt = source_wkt()
    for path, f in zip(tiles, doc["features"]):
        assert list(f) == ["type", "stac_version", "stac_extensions", "id", "geometry", "bbox", "properties", "links",
                           "assets"]
        assert f["type"] == "Feature" and f["stac_version"] == "1.0.0" and f["stac_extensions"] == STAC_EXTENSIONS
        assert f["id"] == path.stem and f["links"] == []
        assert f["assets"] == {"data": {"href": f"./{path.name}", "roles": ["data"]}}
        h = laspy.open(path).header
        p = f["properties"]
        assert p["pc:count"] == h.point_count > 10_000
        assert p["pc:type"] == "lidar" and p["pc:encoding"] == "?"
        assert p["datetime"] == "2015-09-10T00:00:00Z"  # the header's creation date
        assert p["proj:wkt2"] == wkt and "proj:epsg" not in p  # the WKT VLR; no EPSG code in its top level
        box = [*h.mins, *h.maxs]
        assert p["proj:bbox"] == pytest.approx(box, abs=0, rel=0)  # native; bbox in WGS 84 (test_vpc_wgs84.py)
        (x0, y0, _, x1, y1, _) = box
        assert p["proj:geometry"] == {
            "type": "Polygon", "coordinates": [[[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]]}
        assert -124 < f["bbox"][0] < f["bbox"][3] < -123 and 44 < f["bbox"][1] < f["bbox"][4] < 45  # Eugene, OR
        names = [s["name"] for s in p["pc:schemas"]]
        assert names[:3] == ["X", "Y", "Z"] and "intensity" in names and "gps_time" in names
        assert {"name": "gps_time", "type": "floating", "size": 8} in p["pc:schemas"]
    assert sum(f["properties"]["pc:count"] for f in doc["features"]) == 110_000


def test_vpc_in_another_folder_and_wrench_written_hrefs(tiles, tmp_path):
    other = tmp_path / "elsewhere" / "all.vpc"
    other.parent.mkdir()
    write_vpc(other, [describe_tile(p) for p in tiles])
    hrefs = [f["assets"]["data"]["href"] for f in json.loads(other.read_text())["features"]]
    assert hrefs == [f"./../tiles/{p.name}" for p in tiles]
    assert read_vpc(other) == [str(p) for p in tiles]
    # absolute, file:// and bare relative hrefs; the data asset found by its role among others
    doc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "id": "a", "assets": {"data": {"href": str(tiles[0]), "roles": ["data"]}}},
        {"type": "Feature", "id": "b", "assets": {"data": {"href": "file://" + str(tiles[1])}}},
        {"type": "Feature", "id": "c", "assets": {"overview": {"href": "./ov.copc.laz", "roles": ["overview"]},
                                                   "data": {"href": f"tiles/{tiles[2].name}", "roles": ["data"]}}},
    ]}
    hand = tmp_path / "hand.vpc"
    hand.write_text(json.dumps(doc))
    assert read_vpc(hand) == [str(p) for p in tiles[:3]]


def test_read_vpc_errors(tiles, tmp_path):
    def vpc(content) -> str:
        path = tmp_path / "bad.vpc"
        path.write_text(content if isinstance(content, str) else json.dumps(content))
        return str(path)

    def feature(href, **extra):
        return {"type": "Feature", "id": "t", "assets": {"data": {"href": href, "roles": ["data"]}}, **extra}

    p = vpc('{"type": "FeatureCollection", "features": [')
    with pytest.raises(InputFormatError, match=rf"^{p}: not a VPC file: not valid JSON \(Expecting value at line 1, column 44\)$"):
        read_vpc(p)
    p = vpc({"type": "Feature", "features": []})
    with pytest.raises(InputFormatError, match=rf"^{p}: not a VPC file: its \"type\" is 'Feature', not \"FeatureCollection\"$"):
        read_vpc(p)
    p = vpc([1, 2])
    with pytest.raises(InputFormatError, match=r"its \"type\" is 'list', not \"FeatureCollection\""):
        read_vpc(p)
    p = vpc({"type": "FeatureCollection"})
    with pytest.raises(InputFormatError, match=rf"^{p}: not a VPC file: no \"features\" list$"):
        read_vpc(p)
    p = vpc({"type": "FeatureCollection", "features": []})
    with pytest.raises(EmptyInputError, match=rf"^{p}: the VPC lists no files \(its \"features\" list is empty\)$"):
        read_vpc(p)
    missing = tmp_path / "tiles" / "gone.laz"
    p = vpc({"type": "FeatureCollection", "features": [feature(f"./tiles/{tiles[0].name}"), feature("./tiles/gone.laz")]})
    with pytest.raises(InputNotFoundError, match=rf"^{p}: feature 1 \('t'\) lists {missing}, which does not exist$"):
        read_vpc(p)
    p = vpc({"type": "FeatureCollection", "features": [{"type": "Feature", "assets": {}}]})
    with pytest.raises(InputFormatError, match=rf"^{p}: feature 0 has no \"assets\"$"):
        read_vpc(p)
    p = vpc({"type": "FeatureCollection", "features": [{"type": "Point"}]})
    with pytest.raises(InputFormatError, match=rf"^{p}: feature 0 is not a STAC item \(\"type\": \"Feature\"\)$"):
        read_vpc(p)
    # a URL is read as it is (here fsspec's in-memory filesystem: no object there)
    p = vpc({"type": "FeatureCollection", "features": [feature("memory://nowhere/t.laz")]})
    with pytest.raises(InputNotFoundError, match=rf"^{p}: feature 0 \('t'\) lists memory://nowhere/t.laz, which "
                                                 r"does not exist$"):
        read_vpc(p)
    p = vpc({"type": "FeatureCollection", "features": [feature(str(tiles[0])), feature(f"tiles/{tiles[0].name}")]})
    with pytest.raises(InputFormatError, match=rf"^{p}: features 0 and 1 both list {tiles[0]}$"):
        read_vpc(p)
    with pytest.raises(InputNotFoundError, match=rf"^{tmp_path}/none.vpc: no such file$"):
        read_vpc(tmp_path / "none.vpc")


def test_write_vpc_refusals_and_dates(tiles, tmp_path):
    vpc = tmp_path / "a.vpc"
    write_vpc(vpc, [describe_tile(tiles[0])])
    with pytest.raises(DestinationExistsError, match=r"a.vpc exists; pass overwrite=True to replace it"):
        write_vpc(vpc, [describe_tile(tiles[1])])
    write_vpc(vpc, [describe_tile(tiles[1])], overwrite=True)
    assert read_vpc(vpc) == [str(tiles[1])]
    assert sorted(os.listdir(tmp_path)) == ["a.vpc", "tiles"]  # no temporary file left
    with pytest.raises(InvalidParameterError, match=r"VPC entry 0 needs 'path', 'count' and 'bounds'"):
        write_vpc(tmp_path / "b.vpc", [{"path": str(tiles[0]), "count": 3}])
    with pytest.raises(InvalidParameterError, match=r"VPC entry 0 \(.*\): bounds .* are not finite"):
        write_vpc(tmp_path / "b.vpc", [{"path": str(tiles[0]), "count": 3, "bounds": [[0, 0, 0], [np.nan, 1, 1]]}])
    assert not (tmp_path / "b.vpc").exists()
    # no CRS: wrench's empty WKT; no date: 1970-01-01
    simple = describe_tile(shared_file("simple.laz"))
    assert simple["wkt"] is None and simple["datetime"] == "1970-01-01T00:00:00Z"
    write_vpc(tmp_path / "s.vpc", [simple])
    props = json.loads((tmp_path / "s.vpc").read_text())["features"][0]["properties"]
    assert props["proj:wkt2"] == "" and "proj:epsg" not in props
    mega = describe_tile(shared_file("Megaplot.laz"))  # GeoTIFF keys only: the EPSG code's WKT2
    write_vpc(tmp_path / "m.vpc", [mega])
    props = json.loads((tmp_path / "m.vpc").read_text())["features"][0]["properties"]
    assert props["proj:wkt2"].startswith('PROJCRS["NAD83 / UTM zone 17N",') and props["proj:epsg"] == 26917
    assert _datetime([366, 2020]) == "2020-12-31T00:00:00Z"
    assert _datetime([366, 2021]) == "2021-01-01T00:00:00Z"  # out of range: the 1st of January, as wrench
    assert _datetime([60, 2024]) == "2024-02-29T00:00:00Z"
    with pytest.raises(InputFormatError, match=r"not a LAS/LAZ file"):
        describe_tile(shared_file("bun_zipper.ply"))
