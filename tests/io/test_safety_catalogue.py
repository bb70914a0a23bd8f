"""Fault and bad-input catalogue, part 2 (issue 16): data loss, silently wrong numbers, messages.

Each case asserts its specific outcome: the input data is untouched (0 data loss), the wrong data is refused or
flagged by name (0 silently wrong results), and the command ends with one clear line and exit 2, never a
traceback (0 tracebacks). Cases call the validation functions or the CLI in-process (no pipeline run), so the
whole file runs in seconds. Part 1 (malformed files) is ``test_catalogue.py``; :func:`test_catalogue_total`
counts both.
"""
from __future__ import annotations

import hashlib
import os
import stat
from pathlib import Path

import numpy as np
import pytest
import yaml

from selfsense.io import ContractError, check_dataset, load_dataset
from selfsense.io.outputs import MARKER, OutputError, check_output_dir, output_dir

from io_factory import read_any
from test_catalogue import ANY, CASES as PART1, match, mod_log, mod_rig, mod_trials

RNG = np.random.default_rng(16)


def _tree_hash(d: Path) -> dict[str, str]:
    return {str(p.relative_to(d)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(d.rglob("*")) if p.is_file()}


# ---- plausibility: data that reads fine but would give wrong numbers -----------------------------------
def _late_release(df):
    df = df.copy()
    k = int(0.7 * len(df))
    df.loc[:k, "relay"], df.loc[k + 1:, "relay"] = 1.0, 0.0
    return df


def _reshort(frac):
    def f(df):
        df = df.copy()
        df.loc[int(frac * len(df)):, "relay"] = 1.0
        return df
    return f


def _reshort_middle(df):
    df = df.copy()
    df.loc[700:720, "relay"] = 1.0
    return df


def _clip(col, level):
    def f(df):
        x = df[col].to_numpy()
        m = level * np.nanmax(np.abs(x))
        return df.assign(**{col: np.clip(x, -m, m)})
    return f


def _noise(col, sd=1e-3):
    def f(df):
        return df.assign(**{col: sd * np.random.default_rng(3).standard_normal(len(df))})
    return f


def _weak(col, snr):
    """The channel's signal kept, scaled down to ``snr`` times white noise of unit sd (robust 0.5-99.5 % range):
    a live sensor of poor resolution, not a disconnected one."""
    def f(df):
        x = df[col].to_numpy()
        lo, hi = np.percentile(x, [0.5, 99.5])
        sig = (x - np.median(x)) * (snr / (hi - lo))
        return df.assign(**{col: 1e-3 * (sig + np.random.default_rng(5).standard_normal(len(df)))})
    return f


def _tiny(n_short, n_rel):
    """A trial of ``n_short`` shorted and ``n_rel`` connected samples (driven), on a continuous time base."""
    def f(df):
        import pandas as pd

        out = pd.concat([df.iloc[:n_short], df.iloc[500:500 + n_rel]]).reset_index(drop=True)
        return out.assign(t=np.arange(len(out)) * 1e-3)
    return f


PLAUSIBILITY = [
    # (id, mutation, file, field, row, fragment, level)
    ("shunt-scale-1000x-high", mod_rig(lambda r: r.update(shunt_resistance_ohm=1e6)),
     "free_sine.parquet", "v_shunt", None, "ratio 0.001", "error"),
    ("shunt-scale-1000x-low", mod_rig(lambda r: r.update(shunt_resistance_ohm=1.0)),
     "blocked_sine.csv", "v_shunt", None, "ratio 1e+03", "error"),
    ("inamp-gain-100x", mod_rig(lambda r: r.update(inamp_gain=1000.0)),
     "obj_mixed.parquet", "v_shunt", None, "check shunt_resistance_ohm, inamp_gain", "error"),
    ("capacitance-1000x", mod_rig(lambda r: r["actuator_catalog"].update(capacitance_f=0.25e-3)),
     "free_steps.csv", "v_shunt", None, "n_actuators * capacitance_f * V", "error"),
    ("n-actuators-wrong", mod_rig(lambda r: r.update(n_actuators=1)),
     "free_sine.parquet", "v_shunt", None, "ratio 5", "warning"),
    ("shunt-noise-only", mod_log("free_sine.parquet", _noise("v_shunt")),
     "free_sine.parquet", "v_shunt", None, "noise-only or disconnected shunt", "error"),
    ("shunt-clipped-below-adc-range", mod_log("blocked_sine.csv", _clip("v_shunt", 0.5)),
     "blocked_sine.csv", "v_shunt", ANY, "no flat tops", "error"),
    ("laser-clipped-below-adc-range", mod_log("free_steps.csv", _clip("laser", 0.6)),
     "free_steps.csv", "laser", ANY, "no flat tops", "error"),
    ("load-cell-clipped-low", mod_log("blocked_sine.csv", _clip("load_cell", 0.4)),
     "blocked_sine.csv", "load_cell", ANY, "no flat tops", "error"),
    ("relay-released-late", mod_log("free_sine.parquet", _late_release),
     "free_sine.parquet", "relay", ANY, "for at least 50 % of the trial", "error"),
    ("relay-reshorted-for-good", mod_log("blocked_sine.csv", _reshort(0.8)),
     "blocked_sine.csv", "relay", ANY, "re-shorted for good", "error"),
    ("relay-reshorted-middle", mod_log("obj_mixed.parquet", _reshort_middle),
     "obj_mixed.parquet", "relay", 701, "1 later relay = 1 segment", "warning"),
    ("free-tip-recorded-blocked", mod_log("free_sine.parquet", _noise("laser")),
     "free_sine.parquet", "laser", None, "a free tip moves the laser spot", "error"),
    ("free-tip-laser-tiny", mod_log("free_steps.csv", lambda df: df.assign(laser=df.laser * 0.02)),
     "free_steps.csv", "laser", None, "a free-tip displacement of the size", "error"),
    ("laser-scale-100x", mod_rig(lambda r: r["reference"].update(laser_m_per_v=0.2)),
     "free_sine.parquet", "laser", None, "laser_m_per_v wrong?", "error"),
    ("blocked-load-cell-flat", mod_log("blocked_sine.csv", _noise("load_cell")),
     "blocked_sine.csv", "load_cell", None, "a blocked tip presses the load cell", "error"),
    # a weak but live load cell (range ~14 x noise) is a warning; noise alone (about 5 x) stays an error above
    ("blocked-load-cell-weak", mod_log("blocked_sine.csv", _weak("load_cell", 14.0)),
     "blocked_sine.csv", "load_cell", None, "a weak reference", "warning"),
    ("object-never-reached", mod_log("obj_mixed.parquet", _noise("load_cell")),
     "obj_mixed.parquet", "load_cell", None, "the tip reaches the object", "warning"),
    ("three-sample-trial", mod_log("free_sine.parquet", _tiny(1, 2)),
     "free_sine.parquet", "relay", None, "samples with relay = 0 (actuator connected; rig.yaml plausibility.min_samples), found '2 of 3 samples'", "error"),
    ("forty-sample-trial", mod_log("blocked_sine.csv", _tiny(20, 40)),
     "blocked_sine.csv", "relay", None, "at least 50 samples with relay = 0", "error"),
    ("plausibility-limit-from-rig", mod_rig(lambda r: r.update(plausibility={"charge_ratio_warn_max": 0.9})),
     "free_sine.parquet", "v_shunt", None, "ratio in [0.5, 0.9]", "warning"),
]


@pytest.mark.parametrize("case", PLAUSIBILITY, ids=[c[0] for c in PLAUSIBILITY])
def test_plausibility(dataset, case):
    _, mutate, file, field, row, frag, level = case
    mutate(dataset)
    errors, warnings = check_dataset(dataset)
    found = match(errors if level == "error" else warnings, file, field, row, frag)
    assert found, "\n".join(map(str, errors + warnings)) or "nothing found"
    assert found.level == level
    if level == "error":
        with pytest.raises(ContractError):
            load_dataset(dataset)
    else:
        assert not errors and load_dataset(dataset)


@pytest.mark.parametrize("adc", [None, "near"])
@pytest.mark.parametrize("factor, refused", [(None, True), (1.0, False), (1.1, False), (2.0, True), (0.5, True)])
def test_a_shunt_plateau_at_the_declared_current_limit_is_the_amplifiers(dataset, factor, refused, adc):
    """An HV amplifier at its current limit delivers a constant current, which an undithered shunt channel reads as
    one code at its extreme: with the limit declared in rig.yaml (``amplifier_current_limit_a``) a plateau at it
    (within 15 %, on each side of the channel's zero-current level, here 1 V of in-amp offset) passes with a warning
    that names it, one elsewhere is still a clipped channel, and so is any plateau without the declaration -- in the
    plausibility check and, with the plateau near the ADC range (``adc``), in the log check before it."""
    from test_catalogue import mod_log as _mod_log

    rig = yaml.safe_load((dataset / "rig.yaml").read_text())
    x = read_any(dataset / "blocked_sine.csv")["v_shunt"].to_numpy()
    level = 0.5 * float(np.nanmax(np.abs(x)))   # where _clip("v_shunt", 0.5) puts the plateau, around 0 V
    offset = 1.0                                 # then the whole channel 1 V up: the zero-current level moves too
    _mod_log("blocked_sine.csv", lambda df: _clip("v_shunt", 0.5)(df).assign(v_shunt=lambda d: d.v_shunt + offset))(
        dataset)
    if adc == "near":   # the ADC range just above the largest |v_shunt| of any trial: the plateau (above half of
        # it) also meets the log check's clipped-channel rule
        top = max(float(np.nanmax(np.abs(read_any(f)["v_shunt"].to_numpy())))
                  for f in dataset.iterdir() if f.suffix in (".csv", ".parquet") and f.name != "trials.csv")
        assert level + offset >= 0.5 * top / 0.99
        mod_rig(lambda r: r.update(adc_range_v=top / 0.99))(dataset)   # no sample at the rails
    if factor is not None:
        i_lim = factor * level / (rig["inamp_gain"] * rig["shunt_resistance_ohm"])
        mod_rig(lambda r: r.update(amplifier_current_limit_a=i_lim))(dataset)
    errors, warnings = check_dataset(dataset)
    flat = [p for p in errors if p.field == "v_shunt" and ("no flat tops" in str(p) or "clipped channel" in str(p))]
    assert bool(flat) == refused, "\n".join(map(str, errors))
    if not refused:
        assert not errors and load_dataset(dataset)
        assert any("amplifier_current_limit_a" in str(w) and w.field == "v_shunt" for w in warnings), warnings


def test_the_current_limit_is_matched_on_its_own_side():
    """The maximum of v_shunt is matched against zero + limit, the minimum against zero - limit."""
    from selfsense.io.rig import parse_rig

    d = yaml.safe_load((Path(__file__).resolve().parents[2] / "data" / "raw" / "sample" / "rig.yaml").read_text())
    d["amplifier_current_limit_a"] = 1.0 / (d["inamp_gain"] * d["shunt_resistance_ohm"])   # 1 V on the channel
    rig, probs = parse_rig(d)
    assert not probs
    assert rig.at_current_limit(1.2, 0.2, is_max=True) and rig.at_current_limit(-0.8, 0.2, is_max=False)
    assert not rig.at_current_limit(-0.8, 0.2, is_max=True) and not rig.at_current_limit(1.2, 0.2, is_max=False)
    assert not rig.at_current_limit(1.4, 0.2, is_max=True)   # 20 % off the limit


def test_reference_snr_limits_are_ordered_and_noise_alone_fails():
    """The weak-reference warning sits above the error limit (a rig that swaps them is refused by name), and white
    noise alone (a disconnected sensor) reads about 5 x its noise: below the error limit with margin."""
    from selfsense.io.plausibility import DEFAULTS, _noise_sigma, _robust_range, check_plausibility_keys

    assert DEFAULTS["min_reference_snr"] < DEFAULTS["warn_reference_snr"]
    _, probs = check_plausibility_keys({"min_reference_snr": 30.0})
    assert [p.field for p in probs] == ["plausibility.min_reference_snr"]
    x = np.random.default_rng(0).standard_normal(20_000)
    snr = _robust_range(x) / _noise_sigma(x)
    assert 4.5 < snr < 6.0
    assert snr < DEFAULTS["min_reference_snr"] / 1.5


def test_pristine_has_no_plausibility_findings(dataset):
    assert check_dataset(dataset) == ([], [])


@pytest.mark.parametrize("name", ["tweezer_sim", "sample"])
def test_bundled_datasets_are_plausible(name):
    d = Path(__file__).resolve().parents[2] / "data" / "raw" / name
    if not d.is_dir():
        pytest.skip("bundled dataset missing")
    assert check_dataset(d, pipeline=True) == ([], [])


# ---- what the pipeline needs beyond the contract (selfsense validate fails, not a later fit) -------------
PIPELINE = [
    ("no-force-calibration", mod_trials(lambda r: [r[0], r[2], r[3]] + [[r[1][0], r[1][1], "validation",
                                                                       *r[1][3:]]]),
     "reference", "with reference 'force'"),
    ("no-displacement-calibration",
     mod_trials(lambda r: [[*r[0][:5], "force", r[0][6]], *r[1:]]), "reference", "with reference 'displacement'"),
    ("no-validation-trial", mod_trials(lambda r: [[*x[:2], "calibration", *x[3:]] for x in r]),
     "role", "at least one 'validation' trial"),
]


@pytest.mark.parametrize("case", PIPELINE, ids=[c[0] for c in PIPELINE])
def test_pipeline_requirements(dataset, case, capsys):
    from selfsense.cli.validate import main

    _, mutate, field, frag = case
    mutate(dataset)
    errors, _ = check_dataset(dataset, pipeline=True)
    assert match(errors, "trials.csv", field, None, frag), errors
    assert main([str(dataset)]) == 1
    assert frag in capsys.readouterr().out


# ---- YAML: aliases refused, long values truncated -------------------------------------------------------
BOMB = "a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{c}: &{c} [{', '.join(['*' + p] * 10)}]\n" for p, c in zip("abcdefgh", "bcdefghi"))


def _rig_append(text):
    def m(d):
        p = d / "rig.yaml"
        p.write_text(p.read_text() + text)
    return m


YAML_CASES = [
    ("rig-alias-bomb-unknown-key", _rig_append(BOMB.replace("i: &i", "notes: &i")), "no YAML aliases"),
    ("rig-alias-bomb-known-key", lambda d: (d / "rig.yaml").write_text(
        (d / "rig.yaml").read_text().replace("dataset: ds", BOMB + "dataset: ds").replace(
            "n_actuators: 5", "n_actuators: *i")), "no YAML aliases"),
    ("rig-merge-key", lambda d: (d / "rig.yaml").write_text(
        "base: &b {inamp_gain: 10.0}\n<<: *b\n" + (d / "rig.yaml").read_text()), "no YAML aliases"),
    ("rig-long-value", mod_rig(lambda r: r.update(dataset="x" * 100_000)), "more characters"),
    ("rig-long-key", mod_rig(lambda r: r.update({"k" * 5000: 1})), "unknown key"),
    ("rig-plausibility-unknown", mod_rig(lambda r: r.update(plausibility={"charge_ratio": 3})),
     "did you mean 'charge_ratio_min'?"),
    ("rig-plausibility-negative", mod_rig(lambda r: r.update(plausibility={"min_samples": -1})), ">= 0"),
    ("rig-plausibility-inverted", mod_rig(lambda r: r.update(plausibility={"charge_ratio_min": 9.0})),
     "a value <= plausibility.charge_ratio_max"),
    ("rig-plausibility-not-mapping", mod_rig(lambda r: r.update(plausibility=[1, 2])), "a mapping"),
    ("rig-current-limit-not-a-number", mod_rig(lambda r: r.update(amplifier_current_limit_a="5 mA")),
     "amplifier_current_limit_a"),
    ("rig-current-limit-negative", mod_rig(lambda r: r.update(amplifier_current_limit_a=-0.005)),
     "amplifier_current_limit_a"),
    ("rig-current-limit-empty", mod_rig(lambda r: r.update(amplifier_current_limit_a=None)),
     "amplifier_current_limit_a"),
    # YAML keeps the last of two values without a word: the second shunt would rescale every charge
    ("rig-duplicate-key", _rig_append("shunt_resistance_ohm: 1200.0\n"), "duplicate key 'shunt_resistance_ohm'"),
]


@pytest.mark.parametrize("case", YAML_CASES, ids=[c[0] for c in YAML_CASES])
def test_rig_yaml_safety(dataset, case):
    import time

    _, mutate, frag = case
    mutate(dataset)
    t0 = time.process_time()
    errors, _ = check_dataset(dataset)
    assert time.process_time() - t0 < 30  # not a timing test: a runaway alias expansion would take minutes
    msg = "\n".join(map(str, errors))
    assert any(frag in str(p) and p.file == "rig.yaml" for p in errors), msg
    assert all(len(str(p)) < 600 for p in errors), max(map(len, map(str, errors)))


# ---- output folders: no data loss -----------------------------------------------------------------------
def test_output_dir_refuses_foreign_folder(tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("precious")
    with pytest.raises(OutputError, match="did not create"):
        with output_dir(out) as tmp:
            (tmp / "x").write_text("1")
    assert (out / "notes.txt").read_text() == "precious" and not (out / "x").exists()


def test_output_dir_refuses_dataset_even_with_marker(tmp_path, dataset):
    (dataset / MARKER).write_text("")
    before = _tree_hash(dataset)
    with pytest.raises(OutputError, match="rig.yaml/trials.csv"):
        check_output_dir(dataset)
    assert _tree_hash(dataset) == before


def test_output_dir_replaces_own_folder_atomically(tmp_path):
    out = tmp_path / "o"
    with output_dir(out) as tmp:
        (tmp / "a.txt").write_text("1")
    assert (out / MARKER).is_file()
    with output_dir(out) as tmp:
        (tmp / "b.txt").write_text("2")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "b.txt"]  # the old set is gone as a whole


def test_output_dir_failure_keeps_previous(tmp_path):
    out = tmp_path / "o"
    with output_dir(out) as tmp:
        (tmp / "a.txt").write_text("old")
    with pytest.raises(RuntimeError):
        with output_dir(out) as tmp:
            (tmp / "a.txt").write_text("half")
            raise RuntimeError("crash mid-write")
    assert (out / "a.txt").read_text() == "old"
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".o.tmp")] == []


def test_output_dir_force_replaces_foreign(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / "junk").write_text("x")
    with output_dir(out, force=True) as tmp:
        (tmp / "new").write_text("y")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "new"]


def test_output_dir_lock_refuses_second_writer(tmp_path):
    out = tmp_path / "o"
    with output_dir(out) as tmp:
        (tmp / "a").write_text("1")
        with pytest.raises(OutputError, match="another selfsense command"):
            with output_dir(out):
                pass
    assert (out / "a").read_text() == "1"


@pytest.mark.parametrize("where", ["same", "inside", "contains", "symlink"])
def test_output_overlapping_input_refused(tmp_path, where):
    inp = tmp_path / "in"
    inp.mkdir()
    (inp / "f").write_text("keep")
    out = {"same": inp, "inside": inp / "sub", "contains": tmp_path}.get(where)
    if where == "symlink":
        out = tmp_path / "link"
        out.symlink_to(inp)
    with pytest.raises(OutputError, match="input"):
        check_output_dir(out, [inp], force=True)
    assert (inp / "f").read_text() == "keep"


def test_atomic_writes_are_0644_under_umask(tmp_path):
    from selfsense.io import atomic_write_text, savefig_atomic

    old = os.umask(0o022)
    try:
        p = atomic_write_text(tmp_path / "a.txt", "x")
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig = plt.figure()
        q = savefig_atomic(fig, tmp_path / "f.png")
        plt.close(fig)
        os.umask(0o077)
        r = atomic_write_text(tmp_path / "b.txt", "x")
    finally:
        os.umask(old)
    assert stat.S_IMODE(p.stat().st_mode) == 0o644 and stat.S_IMODE(q.stat().st_mode) == 0o644
    assert stat.S_IMODE(r.stat().st_mode) == 0o600  # the umask is respected
    assert q.read_bytes()[:4] == b"\x89PNG"


def test_atomic_write_refuses_any_dataset_folder(tmp_path, dataset):
    from selfsense.io import RawDataWriteError, atomic_write_text

    with pytest.raises(RawDataWriteError, match="inside the raw dataset"):
        atomic_write_text(dataset / "sub" / "x.json", "{}")
    assert not (dataset / "sub").exists()


# ---- CLI: data loss, one-line errors with exit 2, no traceback --------------------------------------------
def _cli(argv, capsys):
    from selfsense.cli import main

    rc = main(argv)
    cap = capsys.readouterr()
    assert "Traceback" not in cap.err + cap.out
    return rc, cap.err


def test_cli_simulate_refuses_foreign_folder(tmp_path, capsys):
    out = tmp_path / "tweezer_copy"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    rc, err = _cli(["simulate", "--preset", "sample", "--out", str(out)], capsys)
    assert rc == 2 and "did not create" in err and "--force" in err
    assert (out / "notes.txt").read_text() == "mine"


def test_cli_simulate_refuses_data_tree(tmp_path, capsys, dataset):
    before = _tree_hash(dataset.parent)
    rc, err = _cli(["simulate", "--preset", "sample", "--out", str(dataset)], capsys)
    assert rc == 2 and "rig.yaml/trials.csv" in err
    rc, err = _cli(["simulate", "--preset", "sample", "--out", str(dataset.parent)], capsys)
    assert rc == 2 and "did not create" in err
    assert _tree_hash(dataset.parent) == before


def test_cli_estimate_out_equal_to_log_refused(tmp_path, capsys, dataset):
    log = tmp_path / "log.parquet"
    log.write_bytes((dataset / "free_sine.parquet").read_bytes())
    model = tmp_path / "m.json"
    model.write_text("{}")
    before = log.read_bytes()
    rc, err = _cli(["estimate", "--model", str(model), "--dataset", str(dataset), "--log", str(log),
                    "--out", str(log)], capsys)
    assert rc == 2 and "resolves to the input" in err and len(err.strip().splitlines()) == 1
    link = tmp_path / "alias.parquet"
    link.symlink_to(log)
    rc, err = _cli(["estimate", "--model", str(model), "--dataset", str(dataset), "--log", str(log),
                    "--out", str(link)], capsys)
    assert rc == 2 and "resolves to the input" in err
    rc, err = _cli(["estimate", "--model", str(model), "--dataset", str(dataset), "--log", str(log),
                    "--out", str(dataset / "est.parquet")], capsys)
    assert rc == 2 and "inside the input" in err
    assert log.read_bytes() == before and not (dataset / "est.parquet").exists()


def test_cli_gap_diagnose_bad_dataset_one_line(tmp_path, capsys, dataset):
    mod_rig(lambda r: r.update(inamp_gain=-1))(dataset)
    rc, err = _cli(["gap", "diagnose", str(dataset), "--out", str(tmp_path / "g")], capsys)
    assert rc == 2 and "inamp_gain" in err and "> 0" in err
    assert not (tmp_path / "g").exists()


def test_cli_gap_diagnose_out_inside_dataset(tmp_path, capsys, dataset):
    before = _tree_hash(dataset)
    rc, err = _cli(["gap", "diagnose", str(dataset), "--out", str(dataset / "gap")], capsys)
    assert rc == 2 and "input" in err
    assert _tree_hash(dataset) == before


def test_cli_gap_diagnose_foreign_out(tmp_path, capsys, dataset):
    out = tmp_path / "g"
    out.mkdir()
    (out / "keep.txt").write_text("k")
    rc, err = _cli(["gap", "diagnose", str(dataset), "--out", str(out)], capsys)
    assert rc == 2 and "did not create" in err and (out / "keep.txt").read_text() == "k"


def test_cli_gap_unknown_option_is_refused(tmp_path, capsys, dataset):
    """An option of the retired tip-level design (--estimator) is an argparse error, not silently ignored."""
    with pytest.raises(SystemExit) as e:
        _cli(["gap", "diagnose", str(dataset), "--out", str(tmp_path / "g"), "--estimator", "sensing"], capsys)
    assert e.value.code == 2
    assert not (tmp_path / "g").exists()


def test_cli_validate_semicolon_csv_hint(dataset, capsys):
    p = dataset / "free_steps.csv"
    df = read_any(p)
    p.write_text(df.to_csv(index=False, sep=";", decimal=","))
    rc, _ = _cli(["validate", str(dataset)], capsys)
    assert rc == 1
    errors, _ = check_dataset(dataset)
    mine = [str(e) for e in errors if e.file == "free_steps.csv"]
    assert len(mine) == 1 and "semicolon" in mine[0], mine


def test_cli_validate_comma_decimal_hint(dataset):
    p = dataset / "free_steps.csv"
    df = read_any(p)
    p.write_text(df.to_csv(index=False, sep=",", decimal=",", quoting=1))
    errors, _ = check_dataset(dataset)
    mine = [str(e) for e in errors if e.file == "free_steps.csv"]
    assert any("decimal comma" in m for m in mine), mine


def test_cli_internal_error_is_one_line(monkeypatch, capsys):
    import selfsense.cli.validate as vcli

    def boom(argv):
        raise ZeroDivisionError("x" * 10_000)
    monkeypatch.setattr(vcli, "main", boom)
    rc, err = _cli(["validate", "whatever"], capsys)
    assert rc == 1 and "internal error (ZeroDivisionError" in err and len(err) < 800


def test_cli_validate_foreign_byte_in_csv_header(dataset):
    """A byte of another encoding in a CSV header is reported with its line, not dropped from the column name (which
    used to give "column 'load_cll': expected column 'load_cell'", a name the file does not have)."""
    p = dataset / "free_steps.csv"
    p.write_bytes(p.read_bytes().replace(b"load_cell", b"load_c\xe9ll", 1))
    errors, _ = check_dataset(dataset)
    mine = [str(e) for e in errors if e.file == "free_steps.csv"]
    assert len(mine) == 1 and "UTF-8" in mine[0] and "line 1" in mine[0] and "\\xe9" in mine[0], mine


def test_time_stamps_that_cannot_resolve_the_step_are_flagged(dataset):
    """Time stamps offset by 1e12 s resolve only 1.2e-4 s, so a 1 ms step reads as 0.98 or 1.10 ms: the median rate
    still passes, and a warning names the column, the spread and the fix; the pristine log has no such warning."""
    from selfsense.io import check_signals, read_log

    df = read_log(dataset / "free_sine.parquet")
    assert not [p for p in check_signals(df, name="free_sine.parquet") if p.field == "t"]
    far = df.assign(t=df["t"] + 1e12)
    got = [p for p in check_signals(far, name="free_sine.parquet") if p.field == "t"]
    assert len(got) == 1 and got[0].is_warning and "subtract the first time stamp" in str(got[0]), got


def test_cli_run_config_schema_errors_are_one_line_each(tmp_path, capsys, monkeypatch):
    """A misspelt key or a value outside its enumeration in the pipeline config: one line per problem naming the key
    (with the nearest known key) and exit 2 before Snakemake starts, instead of Snakemake's dump of the schema."""
    monkeypatch.chdir(tmp_path)
    rc, err = _cli(["run", "--dry-run", "--config", "calibraton={cv_blocks: 3}", "on_bad_trial=maybe"], capsys)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 2, err
    assert "config key 'calibraton'" in err and "did you mean 'calibration'?" in err
    assert "config key 'on_bad_trial': expected one of 'fail', 'skip', found 'maybe'" in err
    assert not (tmp_path / ".snakemake").exists()


# ---- pipeline config: refused when it loads ------------------------------------------------------------
def _cfg(**kw):
    cfg = {"datasets": ["ds"], "raw_dir": "data/raw", "results_dir": "results", "calibration": {"solver": "CLARABEL"},
           "gap": {"enabled": True}}
    cfg.update(kw)
    return cfg


CONFIG_CASES = [
    ("results-equals-raw", _cfg(results_dir="data/raw"), "apart from raw_dir"),
    ("results-inside-raw", _cfg(results_dir="data/raw/out"), "apart from raw_dir"),
    ("raw-inside-results", _cfg(results_dir="data"), "apart from raw_dir"),
    ("results-in-dataset", _cfg(raw_dir="raw", results_dir="raw/../raw/ds/res"), "apart from raw_dir"),
    ("unknown-solver", _cfg(calibration={"solver": "NOPE"}), "expected an installed cvxpy solver"),
    ("solver-not-string", _cfg(calibration={"solver": 3}), "a cvxpy solver name"),
    ("results-dir-empty", _cfg(results_dir=""), "expected a folder path"),
]


@pytest.mark.parametrize("case", CONFIG_CASES, ids=[c[0] for c in CONFIG_CASES])
def test_config_refused_at_load(tmp_path, case):
    from selfsense.io.config import ConfigError, check_config

    _, cfg, frag = case
    with pytest.raises(ConfigError, match=frag.replace("(", r"\(")):
        check_config(cfg, workdir=tmp_path)


def test_config_results_symlink_into_raw(tmp_path):
    from selfsense.io.config import ConfigError, check_config

    (tmp_path / "data" / "raw").mkdir(parents=True)
    (tmp_path / "res").symlink_to(tmp_path / "data" / "raw")
    with pytest.raises(ConfigError, match="symlinks resolved"):
        check_config(_cfg(results_dir="res"), workdir=tmp_path)
    check_config(_cfg(), workdir=tmp_path)  # the default layout passes


def test_config_alias_bomb_file_refused(tmp_path):
    from selfsense.io.config import ConfigError, check_config

    p = tmp_path / "c.yaml"
    p.write_text(BOMB + "datasets: [ds]\ngap: {enabled: true, extra: *i}\n")
    with pytest.raises(ConfigError, match="aliases"):
        check_config({}, [p], workdir=tmp_path)


def test_config_shared_subtree_refused(tmp_path):
    from selfsense.io.config import ConfigError, check_config

    shared = {"x": [1, 2]}
    with pytest.raises(ConfigError, match="aliases"):
        check_config(_cfg(gap={"a": shared, "b": shared}), workdir=tmp_path)


@pytest.mark.parametrize("gap,ok", [({"enabled": True, "seed": 3}, True),
                                     ({"estimator": "sensing"}, False), ({"enabled": True, "typo": 1}, False),
                                     ({"benchmark": {"n": 2, "tier": "fast"}}, False),
                                     ({"seed": -1}, False)])
def test_schema_gap_block_closed(gap, ok):
    import jsonschema

    schema = yaml.safe_load((Path(__file__).resolve().parents[2] / "workflow/schemas/config.schema.yaml").read_text())
    cfg = {"datasets": ["x"], "gap": gap}
    if ok:
        jsonschema.validate(cfg, schema)
    else:
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(cfg, schema)


def test_run_refuses_bad_config_before_snakemake(tmp_path, capsys, monkeypatch):
    import subprocess

    (tmp_path / "data" / "raw" / "ds").mkdir(parents=True)
    (tmp_path / "config.yaml").write_text("datasets: [ds]\nraw_dir: data/raw\nresults_dir: data/raw\n")
    monkeypatch.setattr(subprocess, "call", lambda *a, **k: pytest.fail("snakemake must not start"))
    monkeypatch.setattr(subprocess, "Popen", lambda *a, **k: pytest.fail("snakemake must not start"))
    rc, err = _cli(["run", "--directory", str(tmp_path)], capsys)
    assert rc == 2 and "apart from raw_dir" in err


# ---- memory: sample budgets (selfsense.io.budget) ---------------------------------------------------------
def test_read_parquet_decimated_is_stride_and_bounded(tmp_path):
    import pandas as pd

    from selfsense.io import read_parquet_decimated

    n = 100_003
    df = pd.DataFrame({"t": np.arange(n) * 1e-4, "x": np.sin(np.arange(n) * 1e-3)})
    p = tmp_path / "long.parquet"
    df.to_parquet(p, index=False)
    got, k = read_parquet_decimated(p, max_rows=10_000, batch_size=7_777)  # batches not a multiple of k
    assert k == 11 and len(got) <= 10_000
    np.testing.assert_array_equal(got["t"].to_numpy(), df["t"].to_numpy()[::k])
    same, k1 = read_parquet_decimated(p, max_rows=n)
    assert k1 == 1 and len(same) == n


def test_block_mean_keeps_relay_shorted_and_means():
    import pandas as pd

    from selfsense.io import block_mean

    df = pd.DataFrame({"q": np.arange(10.0), "relay": [1, 1, 1, 0, 0, 0, 0, 0, 0, 0.0]})
    b = block_mean(df, 4)
    assert b["q"].tolist() == [1.5, 5.5, 8.5] and b["relay"].tolist() == [1.0, 0.0, 0.0]
    assert b.attrs["decimation"] == 4 and block_mean(df, 1) is df


def test_gap_case_decimated_above_budget(dataset):
    from selfsense.gap.data import load_case

    full = load_case(dataset, with_truth=False)
    small = load_case(dataset, with_truth=False, max_samples=500)
    assert full.decimated == {}
    assert small.decimated == {t: 3 for t in full.trials}  # 1500 samples -> block means of 3
    for t, df in small.trials.items():
        assert len(df) == 500
        np.testing.assert_allclose(df["q"].to_numpy(), full.trials[t]["q"].to_numpy().reshape(-1, 3).mean(axis=1))


@pytest.mark.parametrize("file", ["free_sine.parquet", "free_steps.csv"])
def test_trial_above_sample_budget_refused_before_reading(dataset, monkeypatch, file):
    import pandas as pd
    import pyarrow.parquet as pq

    def boom(*a, **k):
        raise AssertionError("the body of a log above the sample budget was read")
    errors, _ = check_dataset(dataset, pipeline=True, max_trial_samples=1000)
    assert match(errors, file, None, None, "at most 1,000 samples per trial"), errors
    assert match(errors, file, None, None, "found '1,500 samples'")
    monkeypatch.setattr(pd, "read_csv", boom)
    monkeypatch.setattr(pq.ParquetFile, "read", boom)
    errors, _ = check_dataset(dataset, pipeline=True, max_trial_samples=1000)
    assert match(errors, file, None, None, "selfsense estimate")


def test_stages_validate_applies_budget(dataset, tmp_path):
    from selfsense import stages

    with pytest.raises(ContractError, match="sample budget"):
        stages.validate(dataset, tmp_path / "v.json", max_trial_samples=1000)
    assert not (tmp_path / "v.json").exists()
    summary = stages.validate(dataset, tmp_path / "v.json")
    assert summary["valid"] and summary["warnings"] == []


def test_catalogue_total():
    """At least 100 fault / bad-input cases in the two catalogue files (tables + single-case tests here)."""
    singles = [k for k, v in globals().items() if k.startswith("test_") and callable(v)
               and k not in {"test_catalogue_total", "test_pristine_has_no_plausibility_findings", "test_plausibility",
                             "test_pipeline_requirements", "test_rig_yaml_safety", "test_config_refused_at_load"}]
    n = len(PART1) + len(PLAUSIBILITY) + len(PIPELINE) + len(YAML_CASES) + len(CONFIG_CASES) + len(singles)
    assert n >= 100, n


def test_broken_rig_with_a_channel_map_is_not_buried_under_column_errors(dataset):
    """A rig.yaml whose channel_map says how to read the logs, broken elsewhere: its own problem and one line saying
    the logs wait for it, instead of a false 'unknown column' for every column of every log."""
    r = yaml.safe_load((dataset / "rig.yaml").read_text())
    r["inamp_gain"] = "5"
    r["channel_map"] = {"columns": {"t": "t"}}
    (dataset / "rig.yaml").write_text(yaml.safe_dump(r, sort_keys=False))
    errors, _ = check_dataset(dataset)
    assert {e.file for e in errors} == {"rig.yaml"} and len(errors) == 2, "\n".join(map(str, errors))
    assert any(e.field == "inamp_gain" for e in errors) and any("logs were not checked" in str(e) for e in errors)


def test_daq_channel_names_without_a_channel_map_are_one_problem(dataset):
    """A log with the DAQ's own channel names and no channel_map: one problem naming the file's columns and the
    channel_map, not one per column."""
    p = dataset / "free_steps.csv"
    df = read_any(p)
    df.columns = [f"AI{i}_{c}" for i, c in enumerate(df.columns)]
    df.to_csv(p, index=False)
    errors, _ = check_dataset(dataset)
    mine = [str(e) for e in errors if e.file == "free_steps.csv"]
    assert len(mine) == 1 and "channel_map" in mine[0] and "'AI0_t'" in mine[0], mine


def test_config_override_values_are_typed_as_snakemake_types_them():
    """`selfsense run` checks the layered config against the schema before Snakemake: its `--config` values must have
    the types Snakemake gives them (int, float, True/False, else YAML's base loader: strings), or the check would
    refuse what Snakemake accepts (datasets=[2024], calibration={drift: off}) and accept what it refuses."""
    from snakemake.cli import parse_config

    from selfsense.cli.run import _parse_value

    for v in ["3", "1e7", "0.5", "True", "false", "off", "[2024]", "[yes, 1.0]", "{drift: off}", "{cv_blocks: 3}",
              "~", "null", "data/raw", "CLARABEL", ""]:
        assert _parse_value(v) == parse_config([f"key={v}"])["key"], v


def test_yaml_tag_without_constructor_keeps_its_own_message():
    from selfsense.io.yamlsafe import YamlInputError, load_yaml_text

    with pytest.raises(YamlInputError, match="constructor"):
        load_yaml_text("!foo x: 1\n", "rig.yaml")
