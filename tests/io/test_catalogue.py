"""Catalogue of malformed datasets, each made from the valid fixture dataset by one mutation.

Every case asserts the specific problem: file, field (column / rig key), row where it applies, and a
fragment of the message. Row numbers are 1-based data rows.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from selfsense.io import ContractError, load_dataset, validate_dataset

from io_factory import read_any, write_log, write_trials, TRIALS

ANY = object()


# ---- mutation helpers ---------------------------------------------------------------------------
def mod_log(file, fn):
    def m(d: Path):
        p = d / file
        df = read_any(p)
        df = fn(df)
        write_log(df, p)
    return m


def mod_rig(fn):
    def m(d: Path):
        p = d / "rig.yaml"
        r = yaml.safe_load(p.read_text())
        fn(r)
        p.write_text(yaml.safe_dump(r, sort_keys=False))
    return m


def mod_trials(fn, header=None):
    def m(d: Path):
        rows = [list(r) for r in TRIALS]
        rows = fn(rows)
        if header:
            write_trials(rows, d / "trials.csv", header=header)
        else:
            write_trials(rows, d / "trials.csv")
    return m


def mod_text(file, fn):
    def m(d: Path):
        p = d / file
        p.write_text(fn(p.read_text()))
    return m


def setcell(col, i, val):
    def f(df):
        df = df.copy()
        if isinstance(val, str):
            df[col] = df[col].map(repr).astype(object)
        df.loc[i, col] = val
        return df
    return f


def _swap_t(df):
    df = df.copy()
    t = df["t"].to_numpy().copy()
    t[50], t[51] = t[51], t[50]
    df["t"] = t
    return df


def _nested(key, sub, val):
    def f(r):
        r[key][sub] = val
    return f


def _truncate_half(d):
    p = d / "free_sine.parquet"
    b = p.read_bytes()
    p.write_bytes(b[: len(b) // 2])


def _corrupt_middle(d):
    p = d / "free_sine.parquet"
    b = bytearray(p.read_bytes())
    for i in range(8, len(b) // 2):
        b[i] = 0xFF
    p.write_bytes(bytes(b))


def _rig_text(text):
    def m(d):
        (d / "rig.yaml").write_text(text)
    return m


def _set(key, val):
    def f(r):
        r[key] = val
    return f


def _del(key):
    def f(r):
        del r[key]
    return f


def _relay_start_open(df):
    df = df.copy()
    df.loc[:49, "relay"] = 0.0
    return df


CASES = [
    # (id, mutation, file, field, row, message fragment)
    ("log-missing-column", mod_log("blocked_sine.csv", lambda df: df.drop(columns="relay")),
     "blocked_sine.csv", "relay", None, "this required column, found 'missing'"),
    # an extra channel is ignored with a note (tests/io/test_own_rig.py), not an error
    ("log-misspelt-column", mod_log("free_steps.csv", lambda df: df.rename(columns={"v_shunt": "v_shnt"})),
     "free_steps.csv", "v_shnt", None, "expected column 'v_shunt' (misspelt?)"),
    ("log-misspelt-column-missing-side", mod_log("free_steps.csv", lambda df: df.rename(columns={"v_shunt": "v_shnt"})),
     "free_steps.csv", "v_shunt", None, "did you mean 'v_shnt'?"),
    ("log-duplicate-column", mod_text("blocked_sine.csv", lambda s: s.replace("relay\n", "relay,relay\n", 1)),
     "blocked_sine.csv", "relay", None, "each column once"),
    ("csv-non-numeric", mod_log("blocked_sine.csv", setcell("u_cmd", 4, "abc")),
     "blocked_sine.csv", "u_cmd", 5, "expected a number, found 'abc'"),
    ("parquet-non-numeric", mod_log("free_sine.parquet", setcell("v_shunt", 6, "x1")),
     "free_sine.parquet", "v_shunt", 7, "found 'x1'"),
    ("nan-required", mod_log("free_sine.parquet", setcell("v_shunt", 9, np.nan)),
     "free_sine.parquet", "v_shunt", 10, "no NaN in a required channel"),
    ("nan-time", mod_log("blocked_sine.csv", setcell("t", 99, np.nan)),
     "blocked_sine.csv", "t", 100, "no NaN"),
    ("inf-u_cmd", mod_log("blocked_sine.csv", setcell("u_cmd", 19, np.inf)),
     "blocked_sine.csv", "u_cmd", 20, "finite values (1 inf)"),
    ("nan-laser-displacement-trial", mod_log("free_steps.csv", setcell("laser", 299, np.nan)),
     "free_steps.csv", "laser", 300, "(reference = 'displacement')"),
    ("nan-load_cell-force-trial", mod_log("obj_mixed.parquet", setcell("load_cell", 0, np.nan)),
     "obj_mixed.parquet", "load_cell", 1, "(reference = 'force')"),
    ("empty-file", mod_text("free_steps.csv", lambda s: ""),
     "free_steps.csv", None, None, "empty file (0 bytes)"),
    ("header-only", mod_text("free_steps.csv", lambda s: s.splitlines()[0] + "\n"),
     "free_steps.csv", None, None, "no data rows"),
    ("one-row", mod_text("free_steps.csv", lambda s: "\n".join(s.splitlines()[:2]) + "\n"),
     "free_steps.csv", None, None, "at least 2 samples"),
    ("ragged-csv", mod_text("blocked_sine.csv", lambda s: s.replace("\n", "\n1,2,3,4,5,6,7,8\n", 3)),
     "blocked_sine.csv", None, 1, "a well-formed CSV row of 6 cells, found '8 cells'"),
    ("duplicated-time", mod_log("free_sine.parquet", setcell("t", 100, 0.099)),
     "free_sine.parquet", "t", 101, "1 duplicated steps"),
    ("decreasing-time", mod_log("blocked_sine.csv", _swap_t),
     "blocked_sine.csv", "t", 52, "decreasing"),
    ("gap-in-time", mod_log("free_sine.parquet", lambda df: df.drop(index=range(500, 510)).reset_index(drop=True)),
     "free_sine.parquet", "t", 501, "no gaps longer than 3 sample periods"),
    ("sample-rate-off", mod_log("obj_mixed.parquet", lambda df: df.assign(t=df.t * 1.1)),
     "obj_mixed.parquet", "t", None, "within 5 % of rig.yaml sample_rate_hz = 1000 Hz"),
    ("time-in-ms", mod_log("obj_mixed.parquet", lambda df: df.assign(t=df.t * 1000)),
     "obj_mixed.parquet", "t", None, "(t logged in ms? then set rig.yaml channel_map"),
    ("saturated-shunt-rails", mod_log("free_sine.parquet", lambda df: df.assign(v_shunt=np.clip(df.v_shunt * 3, -10, 10))),
     "free_sine.parquet", "v_shunt", ANY, "ADC rails (saturation)"),
    ("clipped-load-cell", mod_log("obj_mixed.parquet", lambda df: df.assign(load_cell=np.minimum(df.load_cell * 25, 6.0))),
     "obj_mixed.parquet", "load_cell", ANY, "identical extreme values (clipped channel)"),
    ("relay-never-shorts", mod_log("blocked_sine.csv", lambda df: df.assign(relay=0.0)),
     "blocked_sine.csv", "relay", 1, "never shorts"),
    ("relay-open-at-start", mod_log("blocked_sine.csv", _relay_start_open),
     "blocked_sine.csv", "relay", 1, "relay = 1 (leads shorted) at the start of the log, found 0"),
    ("relay-not-binary", mod_log("free_sine.parquet", setcell("relay", 5, 0.5)),
     "free_sine.parquet", "relay", 6, "0 or 1"),
    ("relay-always-shorted", mod_log("free_sine.parquet", lambda df: df.assign(relay=1.0)),
     "free_sine.parquet", "relay", None, "relay always 1"),
    ("u_cmd-in-mV", mod_log("free_steps.csv", lambda df: df.assign(u_cmd=df.u_cmd * 1000)),
     "free_steps.csv", "u_cmd", ANY, "mV logged as V?"),
    ("u_cmd-in-kV", mod_log("free_steps.csv", lambda df: df.assign(u_cmd=df.u_cmd / 1000)),
     "free_steps.csv", "u_cmd", None, "no drive, or V logged as kV?"),
    ("v_shunt-in-mV", mod_log("blocked_sine.csv", lambda df: df.assign(v_shunt=df.v_shunt * 1000)),
     "blocked_sine.csv", "v_shunt", ANY, "within the +-10 V ADC range (mV logged as V? then scale"),
    ("v_shunt-constant", mod_log("blocked_sine.csv", lambda df: df.assign(v_shunt=0.0)),
     "blocked_sine.csv", "v_shunt", None, "a varying shunt signal"),
    ("parquet-truncated", _truncate_half, "free_sine.parquet", None, None, "truncated or corrupt"),
    ("parquet-corrupt-middle", _corrupt_middle, "free_sine.parquet", None, None, "corrupt"),
    ("csv-binary-garbage", lambda d: (d / "free_steps.csv").write_bytes(b"t,u\x00\x00\x01" * 50),
     "free_steps.csv", None, None, "NUL bytes"),
    # ---- rig.yaml -------------------------------------------------------------------------------
    ("rig-unknown-key", mod_rig(_set("notes", "x")), "rig.yaml", "notes", None, "unknown key"),
    ("rig-misspelt-key", mod_rig(lambda r: r.update(shunt_resistence_ohm=r.pop("shunt_resistance_ohm"))),
     "rig.yaml", "shunt_resistence_ohm", None, "did you mean 'shunt_resistance_ohm'?"),
    ("rig-unknown-nested-key", mod_rig(_nested("reference", "laser_mm_per_v", 1.0)),
     "rig.yaml", "reference.laser_mm_per_v", None, "unknown key"),
    ("rig-missing-key", mod_rig(_del("inamp_gain")), "rig.yaml", "inamp_gain", None, "found 'missing'"),
    ("rig-missing-nested-key", mod_rig(lambda r: r["actuator_catalog"].pop("capacitance_f")),
     "rig.yaml", "actuator_catalog.capacitance_f", None, "found 'missing'"),
    ("rig-zero-resistance", mod_rig(_set("shunt_resistance_ohm", 0.0)),
     "rig.yaml", "shunt_resistance_ohm", None, "expected a value > 0, found 0"),
    ("rig-negative-resistance", mod_rig(_set("shunt_resistance_ohm", -1000.0)),
     "rig.yaml", "shunt_resistance_ohm", None, "a value > 0"),
    ("rig-negative-gain", mod_rig(_set("amplifier_gain", -15.0)), "rig.yaml", "amplifier_gain", None, "> 0"),
    ("rig-zero-inamp-gain", mod_rig(_set("inamp_gain", 0)), "rig.yaml", "inamp_gain", None, "> 0"),
    ("rig-zero-capacitance", mod_rig(_nested("actuator_catalog", "capacitance_f", 0.0)),
     "rig.yaml", "actuator_catalog.capacitance_f", None, "> 0"),
    ("rig-implausible-capacitance", mod_rig(_nested("actuator_catalog", "capacitance_f", 0.25)),
     "rig.yaml", "actuator_catalog.capacitance_f", None, "plausible value"),
    ("rig-implausible-shunt", mod_rig(_set("shunt_resistance_ohm", 1e9)),
     "rig.yaml", "shunt_resistance_ohm", None, "in [1, 1e+07]"),
    ("rig-zero-actuators", mod_rig(_set("n_actuators", 0)), "rig.yaml", "n_actuators", None, "integer >= 1"),
    ("rig-fractional-actuators", mod_rig(_set("n_actuators", 2.5)), "rig.yaml", "n_actuators", None, "an integer"),
    ("rig-wrong-type", mod_rig(_set("sample_rate_hz", "fast")), "rig.yaml", "sample_rate_hz", None,
     "expected a number, found 'fast'"),
    ("rig-bool-is-not-number", mod_rig(_set("amplifier_gain", True)), "rig.yaml", "amplifier_gain", None, "a number"),
    ("rig-zero-laser-scale", mod_rig(_nested("reference", "laser_m_per_v", 0.0)),
     "rig.yaml", "reference.laser_m_per_v", None, "non-zero"),
    ("rig-dataset-name", mod_rig(_set("dataset", "other")), "rig.yaml", "dataset", None, "the folder name 'ds'"),
    ("rig-bad-yaml", _rig_text("dataset: ds\n  bad: [\n"), "rig.yaml", None, None, "valid YAML"),
    ("rig-not-mapping", _rig_text("- 1\n- 2\n"), "rig.yaml", None, None, "a YAML mapping"),
    ("rig-missing-file", lambda d: (d / "rig.yaml").unlink(), "rig.yaml", None, None, "no such file"),
    ("rig-channel-map-unknown", mod_rig(_set("channel_map", {"columns": {"voltage": "AI0"}})),
     "rig.yaml", "channel_map.columns.voltage", None, "canonical channel name"),
    ("rig-bad-format", mod_rig(_set("format", "hdf5")), "rig.yaml", "format", None, "'auto', 'csv', 'parquet', 'tdms' or 'mat'"),
    # ---- trials.csv -----------------------------------------------------------------------------
    ("trials-missing-file", mod_trials(lambda r: r[:1] + [[*r[1][:1], "nope.csv", *r[1][2:]]] + r[2:]),
     "trials.csv", "file", 2, "an existing log file, found 'nope.csv (no such file)'"),
    ("trials-duplicate-id", mod_trials(lambda r: r[:2] + [["free_sine", *r[2][1:]]] + r[3:]),
     "trials.csv", "trial", 3, "a unique trial id (already used in row 1)"),
    ("trials-bad-role", mod_trials(lambda r: r[:2] + [[*r[2][:2], "calib", *r[2][3:]]] + r[3:]),
     "trials.csv", "role", 3, "expected 'calibration' or 'validation' (did you mean 'calibration'?), found 'calib'"),
    ("trials-bad-tip", mod_trials(lambda r: [[*r[0][:3], "open", *r[0][4:]]] + r[1:]),
     "trials.csv", "tip", 1, "'free', 'blocked' or 'object'"),
    ("trials-bad-reference", mod_trials(lambda r: [[*r[0][:5], "laser", r[0][6]]] + r[1:]),
     "trials.csv", "reference", 1, "'displacement' or 'force'"),
    ("trials-bad-signal", mod_trials(lambda r: [[*r[0][:6], "chirp"]] + r[1:]),
     "trials.csv", "signal", 1, "'sine', 'mixed', 'steps' or 'other'"),
    ("trials-bad-id", mod_trials(lambda r: [["free sine!", *r[0][1:]]] + r[1:]),
     "trials.csv", "trial", 1, "[A-Za-z0-9_-]+"),
    ("trials-object-without-size", mod_trials(lambda r: r[:2] + [[*r[2][:4], "", *r[2][5:]]] + r[3:]),
     "trials.csv", "object_mm", 3, "positive object size"),
    ("trials-object-negative-size", mod_trials(lambda r: r[:2] + [[*r[2][:4], "-1", *r[2][5:]]] + r[3:]),
     "trials.csv", "object_mm", 3, "found '-1'"),
    ("trials-size-without-object", mod_trials(lambda r: [[*r[0][:4], "3", *r[0][5:]]] + r[1:]),
     "trials.csv", "object_mm", 1, "an empty cell when tip = 'free'"),
    ("trials-path-escape", mod_trials(lambda r: [[r[0][0], "../x.csv", *r[0][2:]]] + r[1:]),
     "trials.csv", "file", 1, "inside the dataset folder"),
    ("trials-not-a-log", mod_trials(lambda r: [[r[0][0], "rig.yaml", *r[0][2:]]] + r[1:]),
     "trials.csv", "file", 1, "a .csv, .parquet, .tdms or .mat log"),
    ("trials-same-file-twice", mod_trials(lambda r: r[:3] + [[r[3][0], r[0][1], *r[3][2:]]]),
     "trials.csv", "file", 4, "file already used in row 1"),
    ("trials-no-calibration", mod_trials(lambda r: [[*x[:2], "validation", *x[3:]] for x in r]),
     "trials.csv", "role", None, "at least one 'calibration' trial"),
    ("trials-no-free-calibration", mod_trials(lambda r: [[*x[:2], "validation" if x[3] == "free" else x[2], *x[3:]]
                                                         for x in r]),
     "trials.csv", "tip", None, "calibration trial with a free tip"),
    ("trials-missing-column", mod_trials(lambda r: [x[:6] for x in r],
                                         header=("trial", "file", "role", "tip", "object_mm", "reference")),
     "trials.csv", "signal", None, "this required column"),
    ("trials-misspelt-column", mod_trials(lambda r: r, header=("trial", "file", "role", "tip", "object_mm",
                                                               "referense", "signal")),
     "trials.csv", "referense", None, "column 'reference' (misspelt?)"),
    ("trials-empty", mod_text("trials.csv", lambda s: ""), "trials.csv", None, None, "empty file"),
    ("trials-no-rows", mod_text("trials.csv", lambda s: s.splitlines()[0] + "\n"), "trials.csv", None, None,
     "at least one trial row"),
    ("trials-ragged-row", mod_text("trials.csv", lambda s: s + "x,y\n"), "trials.csv", None, 5, "7 cells"),
]


def match(problems, file, field, row, frag):
    for p in problems:
        if p.file == file and p.field == field and (row is ANY or p.row == row) and frag in str(p):
            return p
    return None


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_malformed_dataset(dataset, case):
    _, mutate, file, field, row, frag = case
    d = dataset
    mutate(d)
    with pytest.raises(ContractError) as ei:
        load_dataset(d)
    problems = ei.value.problems
    assert match(problems, file, field, row, frag), "\n".join(map(str, problems)) or "no problems"
    for p in problems:
        assert "\n" not in str(p) and str(p).startswith(p.file + ": ")
        assert str(p) in str(ei.value)


def test_pristine_is_valid_and_validate_equals_load(dataset):
    assert validate_dataset(dataset) == []
    assert load_dataset(dataset).rig.dataset == "ds"
    mod_rig(_set("notes", 1))(dataset)
    mod_log("free_sine.parquet", setcell("v_shunt", 9, np.nan))(dataset)
    probs = validate_dataset(dataset)
    with pytest.raises(ContractError) as ei:
        load_dataset(dataset)
    assert ei.value.problems == probs and len(probs) == 2


def test_catalogue_is_large():
    assert len(CASES) >= 25


def test_problem_one_line_format():
    from selfsense.io import Problem

    p = Problem("trials.csv", "role", 3, "'calibration' or 'validation'", "calib")
    assert str(p) == "trials.csv: column 'role', row 3: expected 'calibration' or 'validation', found 'calib'"
    assert str(Problem("rig.yaml", "inamp_gain", None, "a value > 0", -1.0)) == \
        "rig.yaml: key 'inamp_gain': expected a value > 0, found -1"
    assert str(Problem("x.csv", None, None, "a header\nline")) == "x.csv: expected a header line"


def test_problems_collected_across_files(dataset):
    d = dataset
    mod_rig(_set("notes", 1))(d)
    mod_log("free_sine.parquet", setcell("v_shunt", 9, np.nan))(d)
    mod_log("blocked_sine.csv", lambda df: df.assign(relay=0.0))(d)
    probs = validate_dataset(d)
    assert {p.file for p in probs} == {"rig.yaml", "free_sine.parquet", "blocked_sine.csv"}


def test_multiple_problems_in_one_log(dataset):
    d = dataset
    mod_log("free_sine.parquet", lambda df: setcell("t", 100, 0.099)(setcell("relay", 5, 0.5)(df)))(d)
    probs = validate_dataset(d)
    assert match(probs, "free_sine.parquet", "t", 101, "duplicated")
    assert match(probs, "free_sine.parquet", "relay", 6, "0 or 1")


# ---- huge files: must fail from the header / magic bytes, never read whole -------------------------
def _forbid_body_reads(monkeypatch):
    import pyarrow.parquet as pq

    def boom(*a, **k):
        raise AssertionError("the body of a bad 2 GB file was read")
    monkeypatch.setattr(pd, "read_csv", boom)
    monkeypatch.setattr(pq, "ParquetFile", boom)
    monkeypatch.setattr(pq, "read_table", boom)


def _sparse(path: Path, head: bytes, size: int = 2 * 1024**3):
    with open(path, "wb") as fh:
        fh.write(head)
    os.truncate(path, size)  # sparse: no disk space, no time


@pytest.mark.parametrize("head,fragment", [
    (b"time,foo,bar\n", "NUL bytes"),                              # wrong header, then 2 GB of zeros
    (b"t,u_cmd,v_shunt,laser,load_cell,relay\n0,0,0,0,0,1\n", "NUL bytes"),  # right header, corrupt body
])
def test_huge_sparse_csv_fails_early(dataset, monkeypatch, head, fragment):
    d = dataset
    _sparse(d / "free_steps.csv", head)
    _forbid_body_reads(monkeypatch)
    probs = validate_dataset(d)
    assert match(probs, "free_steps.csv", None, None, fragment), probs


def test_huge_csv_with_wrong_header_fails_from_header(dataset, monkeypatch):
    d = dataset
    p = d / "free_steps.csv"
    # a wrong header followed by plain text; extended to 2 GB with a text tail so no NUL check applies
    with open(p, "wb") as fh:
        fh.write(b"time,u_cmd,v_shunt,laser,load_cell,relay\n0,0,0,0,0,1\n")
        fh.seek(2 * 1024**3 - 120)
        fh.write(b"\n" + b"1,1,1,1,1,0\n" * 9 + b"1,1,1,1,1\n")
    import selfsense.io.logs as logs
    monkeypatch.setattr(logs, "_PROBE", 48)  # keep the probe windows off the sparse hole (zeros)
    with open(p, "rb") as fh:
        assert b"\x00" not in fh.read(48)
    _forbid_body_reads(monkeypatch)
    probs = validate_dataset(d)
    assert match(probs, "free_steps.csv", "time", None, "column 't' (misspelt?)"), probs


def test_huge_sparse_parquet_fails_early(dataset, monkeypatch):
    d = dataset
    _sparse(d / "free_sine.parquet", b"PAR1")
    _forbid_body_reads(monkeypatch)
    probs = validate_dataset(d)
    assert match(probs, "free_sine.parquet", None, None, "missing magic bytes: truncated or corrupt file")
