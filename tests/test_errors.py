"""errors.py holds every exception and warning; what cloudsieve raises on bad input is a
CloudsieveError that is also the matching built-in exception (real calls, exact messages)."""

from __future__ import annotations

import inspect
import re

import numpy as np
import pytest
from conftest import shared_file

import cloudsieve
from cloudsieve import errors
from cloudsieve.errors import (
    ArrayNotFoundError,
    CloudsieveError,
    ConvergenceWarning,
    InvalidParameterError,
    MissingDependencyError,
    PartitionLayoutError,
)
from cloudsieve.evaluate import evaluate
from cloudsieve.evaluate.baselines import fps_subset, random_subset, run_method
from cloudsieve.evaluate.points import PointLevel, point_errors
from cloudsieve.io import open_reader
from cloudsieve.store import PointStore, export, ingest


@pytest.fixture
def las_store(tmp_path):
    return ingest(shared_file("simple.las"), tmp_path / "s.zarr", chunk_size=300)


def raises(cls, builtin, message):
    """pytest.raises for *cls*, checking that it is a CloudsieveError and a *builtin*."""
    assert issubclass(cls, CloudsieveError) and issubclass(cls, builtin), (cls, builtin)
    return pytest.raises(cls, match=re.escape(message))


def test_every_exception_and_warning_lives_in_errors():
    classes = [getattr(errors, name) for name in errors.__all__]
    for cls in classes:
        assert cls.__module__ == "cloudsieve.errors"
        if issubclass(cls, Warning):
            continue
        assert issubclass(cls, CloudsieveError)
        if cls is not CloudsieveError:  # each also a built-in other than Exception
            assert any(b.__module__ == "builtins" and b is not Exception for b in cls.__mro__), cls
    assert issubclass(ConvergenceWarning, UserWarning)
    assert cloudsieve.ConvergenceWarning is ConvergenceWarning
    from cloudsieve.core.cluster import ConvergenceWarning as from_cluster
    from cloudsieve.engine.partition import PartitionLayoutError as from_partition

    assert from_cluster is ConvergenceWarning and from_partition is PartitionLayoutError
    assert issubclass(MissingDependencyError, ImportError)


def test_store_errors(tmp_path, las_store):
    with raises(InvalidParameterError, ValueError, "mode must be 'r', 'r+' or 'a', got 'w'"):
        PointStore.open(las_store.path, mode="w")
    with raises(ArrayNotFoundError, KeyError, f"{las_store.path} has no array 'nope'; input arrays: ["):
        las_store.array("nope")
    try:
        las_store.array("nope")
    except KeyError as exc:  # the message itself, not KeyError's quoted repr
        assert str(exc).startswith(f"{las_store.path} has no array 'nope'")
    las_store.create_array("stage/a", shape=(3,), dtype="int8")
    with raises(ArrayNotFoundError, KeyError, f"{las_store.path}: 'stage' is a group, not an array"):
        las_store.array("stage")
    with raises(InvalidParameterError, ValueError, "chunk_size must be an integer >= 1, got -5"):
        next(las_store.chunks(chunk_size=-5))
    with raises(InvalidParameterError, ValueError, f"{las_store.path}: 'intensity' is an input array"):
        las_store.create_array("intensity", shape=(1065,), dtype=np.uint16)


def test_ingest_export_errors(tmp_path, las_store):
    with raises(InvalidParameterError, ValueError, "chunk_size must be an integer >= 1, got 0"):
        ingest(shared_file("simple.las"), tmp_path / "t.zarr", chunk_size=0)
    with raises(InvalidParameterError, ValueError, "chunk_size must be an integer >= 1, got 0"):
        open_reader(shared_file("simple.las"), chunk_size=0)
    out = tmp_path / "o.las"
    with raises(InvalidParameterError, ValueError, "mask must be 1-D with 1065 entries (one per point), got shape (3,)"):
        export(las_store, out, mask=np.ones(3, bool))
    with raises(InvalidParameterError, ValueError, "mask must be boolean, got dtype int64"):
        export(las_store, out, mask=np.ones(1065, np.int64))
    with raises(ArrayNotFoundError, KeyError, "has no array 'simplify/keep'"):
        export(las_store, out, mask="simplify/keep")
    assert not out.exists()


def test_partition_layout_error(las_store):
    from cloudsieve.engine.partition import Partition

    with raises(PartitionLayoutError, ValueError, f"{las_store.path} holds no complete partition: partition it again"):
        Partition.load(las_store)


def test_evaluation_errors():
    pts = np.random.default_rng(0).normal(size=(200, 3))
    with raises(InvalidParameterError, ValueError, "points must have shape (n, 3), got (200, 2)"):
        random_subset(pts[:, :2], 10)
    with raises(InvalidParameterError, ValueError, "count must be an integer >= 1, got 0"):
        random_subset(pts, 0)
    assert (random_subset(pts, 500) == np.arange(200)).all()  # a count above the cloud's size keeps them all
    with raises(InvalidParameterError, ValueError, "unknown method 'grid'; choose among km, fcm, random"):
        run_method("grid", pts, 10)
    with raises(InvalidParameterError, ValueError, "fps: 200 points x 100 kept = 2e+04 > 1e+04"):
        fps_subset(pts, 100, max_work=1e4)
    with raises(InvalidParameterError, ValueError, "simplified points must have shape (m, 3), got (5, 2)"):
        point_errors(pts, pts[:5, :2])
    with raises(InvalidParameterError, ValueError, "sample must be an integer >= 1, got 0"):
        point_errors(pts, pts[:5], PointLevel(sample=0))


def test_evaluate_signature_has_no_private_keywords():
    assert not [p for p in inspect.signature(evaluate).parameters if p.startswith("_")]



def test_cli_missing_mask_array(tmp_path, las_store, capsys):
    from cloudsieve.cli import main

    out = tmp_path / "o.las"
    assert main(["export", las_store.path, str(out), "--mask", "simplify/keep", "--no-progress"]) == 2
    assert f"cloudsieve export: error: {las_store.path} has no array 'simplify/keep'\n" in capsys.readouterr().err
    assert not out.exists()
