"""Valid datasets: loading, SI conversion, channel maps, CLI."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import yaml

from selfsense.io import (ContractError, load_dataset, load_rig, load_trials, read_log, trial_signals,
                          validate_dataset)
from selfsense.cli.validate import main as validate_main

from io_factory import RIG, read_any, write_log


def test_load_rig_mirrors_yaml(dataset):
    rig = load_rig(dataset)
    assert rig.dataset == "ds" and rig.n_actuators == 5 and isinstance(rig.n_actuators, int)
    assert rig.reference.laser_m_per_v == 2e-3 and rig.actuator_catalog.capacitance_f == 0.25e-6
    assert rig.format == "auto" and rig.channel_map is None and rig.dt == pytest.approx(1e-3)


def test_yaml_exponent_without_dot_is_a_number(dataset):
    text = (dataset / "rig.yaml").read_text().replace("0.002", "2e-3")
    assert "2e-3" in text
    (dataset / "rig.yaml").write_text(text)
    assert load_rig(dataset).reference.laser_m_per_v == 2e-3


def test_quoted_number_is_a_type_error(dataset):
    r = yaml.safe_load((dataset / "rig.yaml").read_text())
    r["inamp_gain"] = "10"
    (dataset / "rig.yaml").write_text(yaml.safe_dump(r))
    with pytest.raises(ContractError, match=r"rig.yaml: key 'inamp_gain': expected a number, found '10'"):
        load_rig(dataset)


def test_load_trials_types(dataset):
    tr = load_trials(dataset)
    assert list(tr["trial"]) == ["free_sine", "blocked_sine", "obj_mixed", "free_steps"]
    assert np.isnan(tr.loc[0, "object_mm"]) and tr.loc[2, "object_mm"] == 2.5
    assert list(tr["row"]) == [1, 2, 3, 4]


def test_trial_signals_si_conversion(dataset):
    raw = read_any(dataset / "free_sine.parquet")
    si = trial_signals(dataset, "free_sine")
    assert list(si.columns) == ["t", "u_cmd", "V_c", "V_s", "relay", "dx_ref", "f_ref"]
    np.testing.assert_array_equal(si["V_c"], 15.0 * raw["u_cmd"])
    np.testing.assert_array_equal(si["V_s"], raw["v_shunt"] / 10.0)
    np.testing.assert_array_equal(si["dx_ref"], 2 * 2e-3 * raw["laser"])
    assert si["f_ref"].isna().all()  # reference = displacement
    si = trial_signals(dataset, "blocked_sine")
    raw = read_any(dataset / "blocked_sine.csv")
    np.testing.assert_allclose(si["f_ref"], 0.1 * raw["load_cell"], rtol=1e-15)
    assert si["dx_ref"].isna().all()
    # the physics of the fixture: blocked-tip force peaks at 0.1 N * V/V_max (V_max = 150 V, u <= 8 V)
    assert 0.07 < si["f_ref"].max() < 0.085


def test_trial_signals_unknown_trial(dataset):
    with pytest.raises(ContractError, match="trials.csv: column 'trial': expected a trial id listed"):
        trial_signals(dataset, "nope")


def test_reference_channel_may_be_nan_only_when_not_the_reference(dataset):
    # free_sine is a displacement trial: load_cell is NaN and that is fine; laser must be finite
    df = read_log(dataset / "free_sine.parquet", reference="displacement")
    assert df["load_cell"].isna().all() and np.isfinite(df["laser"]).all()
    with pytest.raises(ContractError, match="column 'load_cell', row 1: expected no NaN"):
        read_log(dataset / "free_sine.parquet", reference="force")


def test_read_log_without_rig_skips_rate_check(dataset):
    p = dataset / "free_sine.parquet"
    df = read_any(p)
    write_log(df.assign(t=df.t * 2), p)  # 500 Hz
    assert read_log(p)["t"].iloc[1] == pytest.approx(2e-3)
    with pytest.raises(ContractError, match="sample rate within 5 %"):
        read_log(p, rig=load_rig(dataset))


def test_csv_and_parquet_give_identical_signals(dataset):
    df = read_any(dataset / "free_sine.parquet")
    df.to_csv(dataset / "free_sine.csv", index=False)  # shortest round-trip repr floats
    (dataset / "free_sine.parquet").unlink()
    text = (dataset / "trials.csv").read_text().replace("free_sine.parquet", "free_sine.csv")
    (dataset / "trials.csv").write_text(text)
    a = trial_signals(dataset, "free_sine")
    df.to_parquet(dataset / "free_sine.parquet", index=False)
    (dataset / "trials.csv").write_text(text.replace("free_sine.csv", "free_sine.parquet"))
    b = trial_signals(dataset, "free_sine")
    pd.testing.assert_frame_equal(a, b, check_exact=True)


def test_channel_map_renames_and_scales(dataset):
    """A foreign DAQ layout: other column names, time in ms, shunt channel in mV."""
    p = dataset / "free_sine.parquet"
    df = read_any(p)
    foreign = pd.DataFrame({"Time_ms": df.t * 1000, "AO0": df.u_cmd, "AI1_mV": df.v_shunt * 1000,
                            "laser": df.laser, "load_cell": df.load_cell, "relay": df.relay})
    write_log(foreign, p)
    assert validate_dataset(dataset)  # not canonical: fails without a map
    r = yaml.safe_load((dataset / "rig.yaml").read_text())
    r["channel_map"] = {"columns": {"t": "Time_ms", "u_cmd": "AO0", "v_shunt": "AI1_mV"},
                        "scale": {"t": 1e-3, "v_shunt": 1e-3}}
    # the other logs are canonical: give them the same layout
    for f in ("blocked_sine.csv", "obj_mixed.parquet", "free_steps.csv"):
        d = read_any(dataset / f)
        write_log(d.rename(columns={"t": "Time_ms", "u_cmd": "AO0", "v_shunt": "AI1_mV"})
                  .assign(Time_ms=d.t * 1000, AI1_mV=d.v_shunt * 1000), dataset / f)
    (dataset / "rig.yaml").write_text(yaml.safe_dump(r))
    assert validate_dataset(dataset) == []
    si = trial_signals(dataset, "free_sine")
    np.testing.assert_allclose(si["t"], df.t, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(si["V_s"], df.v_shunt / 10.0, rtol=1e-12)


def test_format_override_reads_csv_with_other_suffix(dataset):
    r = yaml.safe_load((dataset / "rig.yaml").read_text())
    r["format"] = "csv"
    (dataset / "rig.yaml").write_text(yaml.safe_dump(r))
    probs = validate_dataset(dataset)  # parquet files now read as CSV: binary -> clear problems, no crash
    assert {p.file for p in probs} == {"free_sine.parquet", "obj_mixed.parquet"}


def test_load_dataset(dataset):
    ds = load_dataset(dataset)
    assert ds.name == "ds" and len(ds.trials) == 4 and ds.rig.shunt_resistance_ohm == RIG["shunt_resistance_ohm"]


def test_cli_ok(dataset, capsys):
    assert validate_main([str(dataset)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and out[0].startswith(f"OK {dataset}: dataset 'ds', 4 trials (2 calibration, 2 validation)")


def test_cli_problems(dataset, capsys):
    r = yaml.safe_load((dataset / "rig.yaml").read_text())
    r["shunt_resistance_ohm"] = 0
    r["colour"] = "red"
    (dataset / "rig.yaml").write_text(yaml.safe_dump(r))
    assert validate_main([str(dataset)]) == 1
    out = capsys.readouterr().out.strip().splitlines()
    assert sorted(out) == sorted([
        f"{dataset}/rig.yaml: key 'colour': expected no unknown keys, found 'unknown key'",
        f"{dataset}/rig.yaml: key 'shunt_resistance_ohm': expected a value > 0, found 0",
    ])


def test_cli_via_dispatcher(dataset, capsys):
    from selfsense.cli import main

    assert main(["validate", str(dataset)]) == 0
    assert main(["validate", str(dataset / "nope")]) == 1
    assert "expected a dataset folder" in capsys.readouterr().out
