"""Truth device families: physics of each family and recovery of its H(q) by the registry's selected model."""
import numpy as np
import pytest

from selfsense.hysteresis.models.select import DEFAULT_CANDIDATES, select_h_model
from selfsense.sim.families import DEVICE_RANGES, FAMILIES, RANGES, draw_device
from selfsense.sim.simulate import simulate_scenario_in_memory
from selfsense.sim.truth import truth_path

CAL = ("cal_free_sine", "cal_blocked_sine", "cal_free_mixed")
VAL = "val_disp_free_mixed"


def _short(sc):
    """The device's own trials, shortened (the test budget), same protocol."""
    for tr in sc["trials"]:
        tr["duration"] = min(tr["duration"], 12)
    return sc


@pytest.fixture(scope="module", params=FAMILIES)
def device(request):
    sc = _short(draw_device(request.param, 11, "clean"))
    res = simulate_scenario_in_memory(sc, only=set(CAL) | {VAL})
    return request.param, sc, res


def test_family_draws_stay_in_their_documented_ranges(device):
    fam, sc, _ = device
    d = sc["device"]
    assert d["h_family"] == fam
    assert d["n_actuators"] in (3, 4, 5, 6)
    for key in ("alpha_n_per_v", "cp_f", "k_act_n_per_m"):
        lo, hi = RANGES[key][0]
        assert lo <= d[key] <= hi
    assert d["h_sign"] in (-1.0, 1.0)
    # the two objects touch within the stroke the drive reaches, the large one first
    obj = {t["trial"]: t.get("object_mm") for t in sc["trials"]}
    assert obj["val_disp_large_mixed"] > obj["val_disp_small_sine"]
    assert d["tip_opening_m"] * 1e3 > obj["val_disp_large_mixed"]


def test_family_truth_has_hysteresis_and_no_exactly_linear_branch(device):
    """V_H(q) on the free calibration trial encloses area (hysteresis) and is not a straight line."""
    fam, sc, res = device
    _, tr = res["cal_free_sine"]
    q, vh = tr["q_act"].to_numpy(), tr["V_H"].to_numpy()
    area = 0.5 * abs(np.sum(q[:-1] * vh[1:] - q[1:] * vh[:-1]))
    assert area > 1e-3 * np.ptp(q) * np.ptp(vh)
    A = np.column_stack([q, np.ones_like(q)])
    r = vh - A @ np.linalg.lstsq(A, vh, rcond=None)[0]
    assert np.sqrt(np.mean(r ** 2)) > 0.05   # V


#: out-of-sample RMS [V] of the selected model against the truth V_H (up to the linear gauge), per family;
#: measured on this seed (pytest -s tests/sim/test_families.py -k recovers): preisach 0.009, bouc_wen 0.013 (the
#: Duhem model; 0.49 V with the Preisach-class models alone), gpi 0.018, jiles_atherton 0.097 V; rate_kp 0.145 V
#: (its first contact, measured before any estimator change for it: a Preisach grid, no rate dependence)
TOL_V = {"preisach": 0.05, "bouc_wen": 0.06, "gpi": 0.08, "jiles_atherton": 0.3, "rate_kp": 0.35}


def test_selected_h_recovers_each_family_out_of_sample(device):
    """Fitted on the calibration trials (noise-free truth signals, eq. 55 gauge, force column on the blocked trial),
    the selected model predicts the validation trial's V_H up to a linear term within the family's tolerance."""
    fam, sc, res = device
    n, C = sc["device"]["n_actuators"], sc["device"]["catalog_capacitance_f"]
    qs, ys, ex, free = [], [], [], []
    for t in CAL:
        _, tr = res[t]
        m = tr["t"].to_numpy() > 0.75
        q, V, f = tr["q"].to_numpy()[m], tr["V"].to_numpy()[m], tr["f_tip"].to_numpy()[m]
        qs.append(q)
        ys.append(V - q / (n * C))
        ex.append((-f if "blocked" in t else 0 * f)[:, None])
        free.append("free" in t)
    sel = select_h_model(qs, ys, 1e-3, extras=ex, free=free, candidates=DEFAULT_CANDIDATES)
    lin = next(r for r in sel.table if r["kind"] == "linear")
    best = next(r for r in sel.table if r["selected"])
    assert best["cv_rms_mean_v"] < 0.5 * lin["cv_rms_mean_v"]
    _, tr = res[VAL]
    m = tr["t"].to_numpy() > 0.75
    q = tr["q"].to_numpy()[m]
    e = sel.model.predict(q, 1e-3) - (tr["V"].to_numpy()[m] - q / (n * C))
    A = np.column_stack([q, np.ones_like(q)])
    e = e - A @ np.linalg.lstsq(A, e, rcond=None)[0]
    print(f"\n{fam}: out-of-sample RMS {np.sqrt(np.mean(e ** 2)):.3f} V ({sel.model.label()})")
    assert np.sqrt(np.mean(e ** 2)) < TOL_V[fam], (fam, sel.model.label())


def test_bouc_wen_saturates_and_jiles_atherton_follows_its_anhysteretic():
    u = np.concatenate([np.linspace(0, 3, 3000), np.linspace(3, 0, 3000)])
    y = truth_path("bouc_wen", u, [1.0, 6.0, 2.0, 1.0, 1.0])   # z_max = (A / (beta + gamma))^(1/n) = 0.125
    assert np.max(np.abs(y)) == pytest.approx(0.125, rel=0.02)
    assert np.all(np.abs(y) <= 0.125 * 1.001)
    hp = [1.0, 0.2, 0.1, 0.3, 0.0, 0.5, 1.0]
    yj = truth_path("jiles_atherton", u, hp)
    assert np.all(np.isfinite(yj)) and np.ptp(yj) > 0.5
    # ascending and descending branches differ at the same input (hysteresis), and both stay below saturation
    i_up, i_dn = 1000, 5000    # u = 1.0 on both branches
    assert abs(yj[i_up] - yj[i_dn]) > 0.02
    assert np.max(np.abs(yj)) < 1.0


def test_rate_kp_loops_widen_with_rate_and_relax_in_a_hold():
    """The rate-dependent KP family: the same 0 -> 1 -> 0 cycle encloses more area the faster it is run (the
    thresholds widen by c per decade of |du/dt|), is rate-independent at rest (dt <= 0 in the kernel), and a hold after
    a ramp relaxes the output towards the narrower at-rest thresholds."""
    hp = [1.0, 0.5, 0.3, 0.1, 0.15, 1.0]
    u = np.concatenate([np.linspace(0, 1, 500), np.linspace(1, 0, 500)])
    area = lambda y: 0.5 * abs(np.sum(u[:-1] * y[1:] - u[1:] * y[:-1]))  # noqa: E731
    areas = [area(truth_path("rate_kp", u, hp, dt=dt)) for dt in (1e-1, 1e-2, 1e-3, 1e-4)]  # 0.02 .. 20 /s
    assert np.all(np.diff(areas) > 0) and areas[-1] > 1.1 * areas[0]
    # without rate dependence (c = 0) the loop is the same at every rate
    flat = [area(truth_path("rate_kp", u, hp[:4] + [0.0, 1.0], dt=dt)) for dt in (1e-1, 1e-4)]
    assert flat[0] == pytest.approx(flat[1], rel=1e-12)
    up = np.concatenate([np.linspace(0, 0.6, 300), np.full(300, 0.6)])
    y = truth_path("rate_kp", up, hp, dt=1e-3)
    assert abs(y[-1] - y[299]) > 1e-3 and np.all(np.abs(np.diff(y[300:])) < 0.05)
    assert np.all(np.abs(y) <= 1.0)


@pytest.mark.parametrize("family", ["gpi", "rate_kp"])
def test_whole_device_randomisation_draws_in_its_ranges_and_keeps_the_device(family):
    """randomise="device" draws the rig, amplifier, dielectric relaxation and holds within DEVICE_RANGES from a
    stream of its own: everything the family draw gave stays the same device."""
    a = draw_device(family, 5, "drift")
    b = draw_device(family, 5, "drift", randomise="device")
    r = b["randomise"]
    changed = {k for k in a["device"] if a["device"][k] != b["device"][k]}
    assert changed <= {"ecreep_c_v", "ecreep_tau_s", "inamp_gain"}
    assert {k: v for k, v in a["effects"].items()} == {k: v for k, v in b["effects"].items() if k != "amplifier_limits"}
    for key in ("sample_rate_hz", "laser_noise_m", "amplifier_bandwidth_hz", "amplifier_limits", "dielectric_weight",
                "hold_s"):
        lo, hi = DEVICE_RANGES[key][0]
        assert lo <= r[key] <= hi, key
    assert DEVICE_RANGES["adc_bits"][0][0] <= b["device"]["adc_bits"] <= DEVICE_RANGES["adc_bits"][0][1]
    assert b["sample_rate_hz"] * b["substeps"] >= 10000.0
    assert all(0.1 <= t <= 100.0 for t in b["device"]["ecreep_tau_s"])
    for tr in b["trials"]:
        if tr.get("signal") == "mixed":   # long enough for two trapezoids with their holds
            assert tr["hold_s"] == r["hold_s"] and tr["duration"] >= 2 * (0.8 + 2 * r["hold_s"])
    with pytest.raises(ValueError, match="unknown randomisation"):
        draw_device(family, 5, randomise="everything")


def test_unknown_family_and_preset_are_refused():
    with pytest.raises(ValueError, match="unknown device family"):
        draw_device("bogus", 0)
    with pytest.raises(ValueError, match="unknown device preset"):
        draw_device("preisach", 0, "bogus")


def test_cross_device_protocols_and_the_mixed_drive_column():
    """The cross-device benchmark knows the thesis protocol (sines only) and the three-trial one, refuses any other,
    and aggregates the mixed-drive validation trials in their own column."""
    from selfsense.devices import PROTOCOLS, aggregate, aggregate_markdown, run_device

    assert set(PROTOCOLS) == {"thesis", "three_trial"}
    with pytest.raises(ValueError, match="protocol: expected one of"):
        run_device("preisach", "clean", 0, protocol="two_sines")
    recs = [{"family": "gpi", "preset": "clean", "seed": s, "status": "ok", "displacement_pct": d, "force_pct": 2.0,
             "mixed_displacement_pct": m, "mixed_force_pct": 3.0} for s, d, m in ((0, 1.0, 4.0), (1, 3.0, 6.0))]
    agg = aggregate(recs)
    assert agg.loc[0, "displacement_median_pct"] == pytest.approx(2.0)
    assert agg.loc[0, "mixed_displacement_median_pct"] == pytest.approx(5.0)
    assert "5.00 / 3.00" in aggregate_markdown(agg)


def test_device_overrides_are_checked_and_recorded(tmp_path):
    """``selfsense devices bench --set NAME=VALUE`` (run_device's ``device_overrides``): an unknown quantity or a
    malformed item is refused with its name before anything is simulated; a resumed folder made with other
    overrides is refused too, so that two ADCs never mix in one table."""
    import json

    from selfsense.cli.devices import _overrides, main
    from selfsense.devices import bench, run_device

    assert _overrides(["adc_bits=18", "laser_noise_m=1e-6"]) == {"adc_bits": 18, "laser_noise_m": 1e-6}
    with pytest.raises(ValueError, match="expected NAME=VALUE"):
        _overrides(["adc_bits"])
    with pytest.raises(ValueError, match="--set adc_bits: expected a number"):
        _overrides(["adc_bits=many"])
    with pytest.raises(ValueError, match=r"unknown device quantities \['adc_bitz'\]"):
        run_device("preisach", "clean", 0, device_overrides={"adc_bitz": 18})
    assert main(["bench", "--n", "1", "--families", "gpi", "--presets", "clean", "--set", "adc_bits",
                 "--out", str(tmp_path / "x")]) == 2
    rec_dir = tmp_path / "b" / "records"
    rec_dir.mkdir(parents=True)
    (rec_dir / "gpi_clean_0.json").write_text(json.dumps(
        {"family": "gpi", "preset": "clean", "seed": 0, "protocol": "thesis", "randomise": "device",
         "override_adc_bits": 18, "status": "ok", "displacement_pct": 1.0, "force_pct": 1.0}))
    with pytest.raises(ValueError, match="device overrides"):
        bench(1, ["gpi"], ["clean"], 1, tmp_path / "b", protocol="thesis", randomise="device", progress=False)
    out = bench(1, ["gpi"], ["clean"], 1, tmp_path / "b", protocol="thesis", randomise="device", progress=False,
                device_overrides={"adc_bits": 18})   # resumed: nothing simulated
    assert out.loc[0, "displacement_median_pct"] == pytest.approx(1.0)


def test_forced_members_are_checked_and_recorded(tmp_path):
    """``selfsense devices bench --member NAME=on|off`` (run_device's ``members``): an unknown member or mode is
    refused with its name before anything is simulated (not recorded as a failed calibration), and a resumed folder
    made with other forced members is refused, so that forced and decided members never mix in one table."""
    import json

    from selfsense.cli.devices import _members, main
    from selfsense.devices import bench, run_device

    assert _members(["offset_drift=on", "leakage=off"]) == {"offset_drift": "on", "leakage": "off"}
    for bad in (["offset_drift"], ["offset_drift=maybe"]):
        with pytest.raises(ValueError, match="--member: expected NAME=on or NAME=off"):
            _members(bad)
    with pytest.raises(ValueError, match=r"unknown members \['drift'\]"):
        _members(["drift=on"])
    with pytest.raises(ValueError, match=r"unknown members \['ofset_drift'\]"):
        run_device("preisach", "clean", 0, members={"ofset_drift": "on"})
    with pytest.raises(ValueError, match=r"members\['leakage'\]: expected 'auto', 'on' or 'off'"):
        bench(1, ["gpi"], ["clean"], 1, tmp_path / "y", members={"leakage": "sometimes"})
    assert not (tmp_path / "y").exists()
    assert main(["bench", "--n", "1", "--families", "gpi", "--presets", "clean", "--member", "offset_drift=yes",
                 "--out", str(tmp_path / "x")]) == 2
    rec_dir = tmp_path / "b" / "records"
    rec_dir.mkdir(parents=True)
    (rec_dir / "gpi_clean_0.json").write_text(json.dumps(
        {"family": "gpi", "preset": "clean", "seed": 0, "protocol": "thesis", "randomise": "device",
         "member_offset_drift": "on", "status": "ok", "displacement_pct": 2.0, "force_pct": 1.0}))
    with pytest.raises(ValueError, match="members forced"):
        bench(1, ["gpi"], ["clean"], 1, tmp_path / "b", protocol="thesis", randomise="device", progress=False)
    out = bench(1, ["gpi"], ["clean"], 1, tmp_path / "b", protocol="thesis", randomise="device", progress=False,
                members={"offset_drift": "on"})   # resumed: nothing simulated
    assert out.loc[0, "displacement_median_pct"] == pytest.approx(2.0)


def test_an_invalid_simulated_dataset_is_recorded_with_its_problems(monkeypatch):
    """A device whose simulated dataset breaks the data contract is a benchmark failure recorded as
    ``invalid_dataset`` with the problems themselves (file, field, row, expected, found), not the message's first
    line, which names only the temporary folder it was simulated into."""
    import selfsense.devices as devices
    from selfsense.io.errors import ContractError, Problem

    def broken(sc, with_truth=False):
        raise ContractError([Problem(file="cal_free_sine.parquet", field="v_shunt", row=1706,
                                     expected="no flat tops", found="48 samples (0.23 %) at 8.00171 V")],
                            context="/tmp/selfsense-device-abc/gpi_clean_0")

    monkeypatch.setattr(devices, "simulate_device", broken)
    rec = devices.run_device("gpi", "clean", 0, protocol="thesis", randomise="device")
    assert rec["status"] == "invalid_dataset" and np.isnan(rec["displacement_pct"])
    assert "cal_free_sine.parquet" in rec["error"] and "v_shunt" in rec["error"] and "row 1706" in rec["error"]
    assert "/tmp" not in rec["error"]


def test_effect_free_twin_removes_only_the_named_effect(tmp_path, monkeypatch):
    """``selfsense devices bench --without EFFECT`` (device_scenario's ``without``): the twin is the same device, drives
    and draw with the named effect set to zero and every other effect kept, so that the pair measures that effect's
    cost; a name that is no simulator effect is refused before anything is simulated, and a resumed folder made
    without other effects is refused."""
    import json

    from selfsense.cli.devices import main
    from selfsense.devices import bench, device_scenario, run_device

    base = device_scenario("gpi", "drift", 3, "thesis", "device")
    twin = device_scenario("gpi", "drift", 3, "thesis", "device", without=("offset_drift",))
    assert base["effects"]["offset_drift"] > 0 and twin["effects"]["offset_drift"] == 0.0
    assert {k: v for k, v in twin["effects"].items() if k != "offset_drift"} == \
        {k: v for k, v in base["effects"].items() if k != "offset_drift"}
    assert twin["device"] == base["device"] and twin["trials"] == base["trials"]
    # the clean preset has no leakage: its twin without it is the device itself
    clean = device_scenario("gpi", "clean", 3, "thesis", "device", without=("leakage",))
    assert clean == device_scenario("gpi", "clean", 3, "thesis", "device")
    import selfsense.sim.families as fam

    with monkeypatch.context() as m:   # refused before the draw (which simulates the free stroke)
        m.setattr(fam, "draw_device", lambda *a, **k: pytest.fail("a device was drawn for an unknown effect name"))
        for call in (run_device, device_scenario):
            with pytest.raises(ValueError, match=r"without: unknown effects \['ofset_drift'\]"):
                call("gpi", "drift", 3, without=("ofset_drift",))
    assert main(["bench", "--n", "1", "--families", "gpi", "--presets", "drift", "--without", "drift",
                 "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()
    rec_dir = tmp_path / "b" / "records"
    rec_dir.mkdir(parents=True)
    (rec_dir / "gpi_drift_0.json").write_text(json.dumps(
        {"family": "gpi", "preset": "drift", "seed": 0, "protocol": "thesis", "randomise": "device",
         "without": "leakage", "status": "ok", "displacement_pct": 1.0, "force_pct": 1.0}))
    with pytest.raises(ValueError, match="without the effects 'leakage'"):
        bench(1, ["gpi"], ["drift"], 1, tmp_path / "b", protocol="thesis", randomise="device", progress=False,
              without=("offset_drift",))
    out = bench(1, ["gpi"], ["drift"], 1, tmp_path / "b", protocol="thesis", randomise="device", progress=False,
                without=("leakage",))   # resumed: nothing simulated
    assert out.loc[0, "displacement_median_pct"] == pytest.approx(1.0)


def test_whole_device_rig_declares_the_amplifier_current_limit_and_its_plateau_passes_the_contract():
    """Whole-device randomisation draws an HV amplifier current limit (2-20 mA); its user knows it from the data
    sheet and rig.yaml says so (``amplifier_current_limit_a``). Rate-dependent KP 100 runs into that limit in every
    trial and its 14-bit shunt channel reads the plateau as one code: refused as a clipped channel without the
    declaration (the benchmark recorded the device as an invalid dataset), accepted with it. The blind gap
    simulator, where the amplifier's limits are an effect hidden from the diagnostic, declares nothing; a scenario
    cannot add other rig keys."""
    import yaml

    from selfsense.devices import device_scenario, simulate_device
    from selfsense.io import ContractError
    from selfsense.sim.simulate import load_scenario, simulate_dataset

    sc = device_scenario("rate_kp", "clean", 100, protocol="thesis", randomise="device")
    i_lim = 1e-3 / sc["effects"]["amplifier_limits"]
    assert sc["rig_extra"] == {"amplifier_current_limit_a": pytest.approx(i_lim)}
    _, _, rig, _ = simulate_device(sc)
    assert rig.amplifier_current_limit_a == pytest.approx(i_lim)
    bare = {k: v for k, v in sc.items() if k != "rig_extra"}
    with pytest.raises(ContractError, match="no flat tops"):
        simulate_device(bare)
    # the family draw without whole-device randomisation (as the blind gap campaigns use it): no declaration
    assert "rig_extra" not in device_scenario("rate_kp", "clean", 100)
    with pytest.raises(ValueError, match=r"rig_extra: unknown keys \['adc_bits'\]"):
        load_scenario({**bare, "rig_extra": {"adc_bits": 16}})
