"""Atomic, deterministic artefact writing; refusal to write under data/raw."""
from __future__ import annotations

import json
import os

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from selfsense.io import (RawDataWriteError, assert_not_in_raw, atomic_write, atomic_write_bytes,
                          atomic_write_text, write_json_atomic, write_parquet_atomic)


def _frame(seed=0, n=200):
    rng = np.random.default_rng(seed)
    return pd.DataFrame({"t": np.arange(n) * 1e-3, "V": rng.normal(size=n), "q": rng.normal(size=n) * 1e-6})


def test_failure_mid_write_leaves_no_partial_file(tmp_path):
    p = tmp_path / "out.bin"
    with pytest.raises(RuntimeError):
        with atomic_write(p) as fh:
            fh.write(b"half of the")
            raise RuntimeError("disk on fire")
    assert not p.exists() and list(tmp_path.iterdir()) == []
    # an existing target is left untouched
    atomic_write_bytes(p, b"old")
    with pytest.raises(RuntimeError):
        with atomic_write(p) as fh:
            fh.write(b"new but incomplete")
            raise RuntimeError("boom")
    assert p.read_bytes() == b"old" and [x.name for x in tmp_path.iterdir()] == ["out.bin"]


def test_failure_in_replace_leaves_no_temp(tmp_path, monkeypatch):
    p = tmp_path / "x.json"
    def bad_replace(a, b):
        raise OSError("replace failed")
    monkeypatch.setattr(os, "replace", bad_replace)
    with pytest.raises(OSError):
        write_json_atomic({"a": 1}, p)
    assert list(tmp_path.iterdir()) == []


def test_parquet_failure_mid_serialisation_writes_nothing(tmp_path):
    p = tmp_path / "x.parquet"
    bad = pd.DataFrame({"a": [1.0, 2.0]}, index=[5, 6])  # non-default index: refused before any write
    with pytest.raises(ValueError, match="RangeIndex"):
        write_parquet_atomic(bad, p)
    assert not p.exists() and list(tmp_path.iterdir()) == []


def test_parquet_deterministic_and_round_trips(tmp_path):
    df = _frame()
    a, b = tmp_path / "a.parquet", tmp_path / "b.parquet"
    write_parquet_atomic(df, a)
    write_parquet_atomic(df.copy(), b)
    assert a.read_bytes() == b.read_bytes()
    back = pd.read_parquet(a)
    pd.testing.assert_frame_equal(back, df, check_exact=True)
    md = pq.read_schema(a).metadata or {}
    assert b"pandas" not in md and "__index_level_0__" not in pq.read_schema(a).names
    write_parquet_atomic(_frame(seed=1), b)
    assert a.read_bytes() != b.read_bytes()


def test_json_deterministic(tmp_path):
    obj = {"b": 0.1 + 0.2, "a": [np.float64(1 / 3), np.int64(7)], "c": {"z": 1, "y": np.array([1.5, 2.5])}}
    p = write_json_atomic(obj, tmp_path / "m.json")
    text = p.read_text()
    assert text.index('"a"') < text.index('"b"') < text.index('"c"')
    back = json.loads(text)
    assert back["b"] == 0.1 + 0.2 and back["a"][0] == 1 / 3  # repr floats round-trip exactly
    write_json_atomic(dict(reversed(list(obj.items()))), tmp_path / "n.json")
    assert (tmp_path / "n.json").read_text() == text
    with pytest.raises(ValueError, match="NaN"):
        write_json_atomic({"x": float("nan")}, tmp_path / "nan.json")
    assert not (tmp_path / "nan.json").exists()


def test_refuses_to_write_under_data_raw(tmp_path):
    raw = tmp_path / "data" / "raw" / "ds"
    raw.mkdir(parents=True)
    for write in (lambda p: atomic_write_text(p, "x"), lambda p: write_json_atomic({}, p),
                  lambda p: write_parquet_atomic(_frame(), p)):
        with pytest.raises(RawDataWriteError, match="data/raw"):
            write(raw / "out")
    assert list(raw.iterdir()) == []
    # also through a symlink pointing into data/raw
    link = tmp_path / "innocent"
    link.symlink_to(raw)
    with pytest.raises(RawDataWriteError):
        assert_not_in_raw(link / "f.json")
    assert assert_not_in_raw(tmp_path / "data" / "rawish" / "f") == tmp_path / "data" / "rawish" / "f"
    assert assert_not_in_raw(tmp_path / "results" / "raw" / "f")  # only data/raw is protected
