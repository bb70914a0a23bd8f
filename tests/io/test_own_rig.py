"""Bringing one's own rig: extra DAQ channels are ignored with a note, an oscilloscope CSV with preamble lines
and a units row is read, and the plausible range of the drive channel u_cmd is set per rig (rig.yaml drive)."""
from __future__ import annotations

import logging

import numpy as np
import pandas as pd
import pytest
import yaml

from selfsense.io import ContractError, check_log, load_rig, parse_rig, read_log
from selfsense.io.rig import CANONICAL_COLUMNS

from io_factory import RIG, make_log


def _log(**kw) -> pd.DataFrame:
    return make_log("free", "displacement", "sine", **kw)


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_extra_channels_are_ignored_with_a_note(tmp_path, suffix, caplog):
    df = _log()
    p = tmp_path / f"log{suffix}"
    wide = df.assign(temperature_c=21.5, AI7=np.linspace(0, 1, len(df)))
    wide.to_csv(p, index=False) if suffix == ".csv" else wide.to_parquet(p, index=False)
    with caplog.at_level(logging.WARNING, logger="selfsense.io"):
        got = read_log(p)
    assert list(got.columns) == list(CANONICAL_COLUMNS)
    np.testing.assert_allclose(got["v_shunt"], df["v_shunt"], rtol=1e-12)
    assert any("extra column(s) 'temperature_c', 'AI7' ignored" in r.getMessage() for r in caplog.records)


def test_extra_column_still_reported_when_a_required_one_is_missing(tmp_path):
    p = tmp_path / "log.csv"
    _log().rename(columns={"v_shunt": "v_shnt"}).to_csv(p, index=False)
    _, probs = check_log(p)
    msgs = [str(x) for x in probs]
    assert any("v_shnt" in m and "misspelt" in m for m in msgs), msgs


def test_scope_csv_with_preamble_and_units_row(tmp_path, caplog):
    df = _log()
    p = tmp_path / "scope.csv"
    body = df.to_csv(index=False, float_format="%.9g").splitlines()
    units = ",".join(["s", "V", "V", "V", "V", "-"])
    text = "\n".join(["Model,DSO-X 2024A", "Date,2026-11-23 10:00:00", "Sample rate,1000,Sa/s", "",
                      body[0], units, *body[1:]]) + "\n"
    p.write_text(text)
    with caplog.at_level(logging.WARNING, logger="selfsense.io"):
        got = read_log(p)
    assert len(got) == len(df)
    np.testing.assert_allclose(got["u_cmd"], df["u_cmd"], rtol=1e-8)
    notes = " ".join(r.getMessage() for r in caplog.records)
    assert "4 preamble line(s)" in notes and "units row" in notes
    # a bad cell is still reported with its data-row number (preamble and units row not counted)
    lines = text.splitlines()
    cells = lines[6 + 9].split(",")
    cells[1] = "abc"
    lines[6 + 9] = ",".join(cells)
    p.write_text("\n".join(lines) + "\n")
    _, probs = check_log(p)
    assert [(x.field, x.row) for x in probs] == [("u_cmd", 10)]


def _rig(**extra) -> dict:
    r = yaml.safe_load(yaml.safe_dump(RIG))
    r.update(extra)
    return r


def test_bipolar_drive_needs_and_accepts_a_declared_range(tmp_path):
    df = _log()
    df["u_cmd"] = 2.0 * df["u_cmd"] - df["u_cmd"].max()  # -8 .. +8 V
    df.loc[:199, "u_cmd"] = 0.0
    p = tmp_path / "bipolar.parquet"
    df.to_parquet(p, index=False)
    rig_default, probs = parse_rig(_rig())
    assert not probs
    _, probs = check_log(p, rig_default, "displacement")
    assert [x.field for x in probs] == ["u_cmd"]
    assert "rig.yaml drive" in str(probs[0]) and "u_cmd >= -1 V" in str(probs[0])
    rig, probs = parse_rig(_rig(drive={"u_cmd_min_v": -10.0, "u_cmd_max_v": 10.0}))
    assert not probs and (rig.u_cmd_min_v, rig.u_cmd_max_v) == (-10.0, 10.0)
    _, probs = check_log(p, rig, "displacement")
    assert not [x for x in probs if x.field == "u_cmd"]


def test_logged_amplifier_output(tmp_path):
    """A rig that logs the amplifier output (0-120 V) in u_cmd: amplifier_gain 1 and drive.u_cmd_max_v."""
    df = _log()
    df["u_cmd"] = 15.0 * df["u_cmd"]
    p = tmp_path / "hv.parquet"
    df.to_parquet(p, index=False)
    rig, probs = parse_rig(_rig(amplifier_gain=1.0, drive={"u_cmd_max_v": 160.0}))
    assert not probs
    _, probs = check_log(p, rig, "displacement")
    assert not [x for x in probs if x.field == "u_cmd"], probs
    rig0, _ = parse_rig(_rig(amplifier_gain=1.0))
    _, probs = check_log(p, rig0, "displacement")
    assert any(x.field == "u_cmd" and "mV logged as V" in str(x) for x in probs)


@pytest.mark.parametrize("drive, field, fragment", [
    ({"u_cmd_min_v": 5.0, "u_cmd_max_v": 1.0}, "drive", "u_cmd_min_v < u_cmd_max_v"),
    ({"u_cmd_max": 10.0}, "drive.u_cmd_max", "only 'u_cmd_min_v' and 'u_cmd_max_v'"),
    ({"u_cmd_max_v": "ten"}, "drive.u_cmd_max_v", "a finite number of volts"),
    ([1, 2], "drive", "a mapping"),
])
def test_bad_drive_key(drive, field, fragment):
    rig, probs = parse_rig(_rig(drive=drive))
    assert rig is None
    assert [(x.field, fragment in str(x)) for x in probs] == [(field, True)]


def test_drive_in_rig_yaml_file(tmp_path):
    d = tmp_path / "ds"
    d.mkdir()
    (d / "rig.yaml").write_text(yaml.safe_dump(_rig(drive={"u_cmd_min_v": -10.5})))
    rig = load_rig(d)
    assert rig.u_cmd_min_v == -10.5 and rig.u_cmd_max_v == 10.5
    with pytest.raises(ContractError):
        (d / "rig.yaml").write_text(yaml.safe_dump(_rig(drive={"u_cmd_min_v": 20})))
        load_rig(d)


def test_rig_value_reads_the_same_number_from_a_rig_and_from_its_yaml_mapping():
    from pathlib import Path

    from selfsense.io.rig import rig_value

    path = Path(__file__).resolve().parents[2] / "data" / "raw" / "sample" / "rig.yaml"
    raw = yaml.safe_load(path.read_text())
    rig = load_rig(path.parent)
    for keys in (("shunt_resistance_ohm",), ("amplifier_gain",), ("actuator_catalog", "capacitance_f")):
        expect = raw
        for k in keys:
            expect = expect[k]
        assert rig_value(rig, *keys) == rig_value(raw, *keys) == float(expect)
    with pytest.raises((KeyError, AttributeError)):
        rig_value(raw, "no_such_key")
