"""The demo: the main job end to end on the built-in example scan."""

from __future__ import annotations

import json

import laspy
import numpy as np

from cloudsieve.cli import main
from cloudsieve.synthetic import scene_chunks


def test_example_scene_is_deterministic_and_chunked():
    a = list(scene_chunks(25_000, seed=4, chunk_size=10_000))
    b = list(scene_chunks(25_000, seed=4, chunk_size=10_000))
    assert [len(c["xyz"]) for c in a] == [10_000, 10_000, 5_000]
    for ca, cb in zip(a, b):
        for name in ca:
            np.testing.assert_array_equal(ca[name], cb[name])
    assert set(np.unique(np.concatenate([c["classification"] for c in a]))) == {2, 5, 6}


def test_demo_runs_end_to_end(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--points", "20000", "--out", str(out), "--scheduler", "sync"]) == 0
    text = capsys.readouterr().out
    assert "kept 10,000 of 20,000 points" in text
    with laspy.open(out / "scene-simplified.laz") as f:
        assert f.header.point_count == 10_000
        assert f.header.point_format.id == 7
    report = json.loads((out / "report" / "report.json").read_text())
    assert report["point"]["forward"]["rms_pct"] > 0
