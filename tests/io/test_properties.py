"""Property-based tests: valid inputs never crash and pass; invalid inputs only ever give ContractError."""
from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from selfsense.io import ContractError, load_dataset, trial_signals, validate_dataset
from selfsense.signals import prepare_trial

from io_factory import RIG, make_dataset
from test_catalogue import CASES

SETTINGS = settings(max_examples=15, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


@st.composite
def valid_params(draw):
    fs = draw(st.sampled_from([200.0, 1000.0, 2500.0]))
    freq = draw(st.floats(0.5, 1.5))
    n_relay = draw(st.integers(2, 100))
    # at least half a drive period connected, and connected for most of the trial (plausibility: relay)
    n = n_relay + max(int(fs / (2 * freq)), n_relay) + draw(st.integers(10, 300))
    return dict(fs=fs, freq_hz=freq, n=n, n_relay=n_relay, amp_v=draw(st.floats(0.5, 8.0)),
                noise_v=draw(st.sampled_from([0.0, 1e-4, 3e-3])), seed=draw(st.integers(0, 2**16)),
                fmt=draw(st.sampled_from(["csv", "parquet"])))


def _trials(fmt):
    from io_factory import TRIALS

    return [(t, f.rsplit(".", 1)[0] + "." + fmt, *rest) for t, f, *rest in TRIALS]


@SETTINGS
@given(p=valid_params())
def test_valid_datasets_pass_and_prepare(p):
    rig = dict(RIG, sample_rate_hz=p["fs"])
    with tempfile.TemporaryDirectory() as tmp:
        d = make_dataset(Path(tmp), rig=rig, trials=_trials(p["fmt"]), seed=p["seed"], n=p["n"], fs=p["fs"],
                         freq_hz=p["freq_hz"], n_relay=p["n_relay"], amp_v=p["amp_v"], noise_v=p["noise_v"])
        assert validate_dataset(d) == []
        ds = load_dataset(d)
        for trial in ds.trials["trial"]:
            pr = prepare_trial(trial_signals(d, trial, rig=ds.rig), ds.rig)
            assert len(pr) == p["n"] and np.isfinite(pr[["t", "V", "q"]].to_numpy()).all()
            assert (pr.loc[pr.relay == 1, "q"] == 0).all()


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("base"))


@SETTINGS
@given(case=st.sampled_from(CASES), case2=st.sampled_from(CASES))
def test_invalid_datasets_only_raise_contract_error(base, case, case2):
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(shutil.copytree(base, Path(tmp) / "ds"))
        for c in (case, case2):
            try:
                c[1](d)
            except (FileNotFoundError, KeyError, ValueError, IndexError, AttributeError):
                pass  # the first mutation may have removed what the second one edits
        with pytest.raises(ContractError) as ei:
            load_dataset(d)
        assert ei.value.problems and all("\n" not in str(p) for p in ei.value.problems)


@SETTINGS
@given(target=st.sampled_from(["rig.yaml", "trials.csv", "blocked_sine.csv", "free_sine.parquet"]),
       payload=st.one_of(st.binary(max_size=300), st.text(max_size=300)),
       keep_prefix=st.integers(0, 400))
def test_garbage_files_only_raise_contract_error(base, target, payload, keep_prefix):
    """A file replaced by (a prefix of itself plus) arbitrary bytes or text: never another exception."""
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(shutil.copytree(base, Path(tmp) / "ds"))
        p = d / target
        data = payload.encode("utf-8", "surrogatepass") if isinstance(payload, str) else payload
        p.write_bytes(p.read_bytes()[:keep_prefix] + data)
        probs = validate_dataset(d)
        assert isinstance(probs, list)
        if probs:
            with pytest.raises(ContractError):
                load_dataset(d)
        else:  # garbage that happens to be valid must then load
            load_dataset(d)
        for pr in probs:
            assert "\n" not in str(pr) and "\r" not in str(pr)


@SETTINGS
@given(st.lists(st.integers(-3, 3), min_size=2, max_size=40))
def test_time_order_rule_finds_the_first_duplicated_and_decreasing_step(steps):
    """The one time-order rule of check_signals and ``selfsense estimate``: the first duplicated and the first
    decreasing step and their counts, and nothing where time strictly increases."""
    from selfsense.io.logs import time_steps_not_increasing

    t = np.concatenate([[0.0], np.cumsum(np.asarray(steps, float))])
    got = {what: (k, n) for what, k, n in time_steps_not_increasing(t)}
    d = np.diff(t)
    for what, mask in (("duplicated", d == 0), ("decreasing", d < 0)):
        if mask.any():
            assert got[what] == (int(np.flatnonzero(mask)[0]), int(mask.sum()))
        else:
            assert what not in got
    strictly = np.all(d > 0)
    assert (not got) == strictly


@pytest.mark.parametrize("t2,row,what", [
    ([0.3, 0.3, 0.25, 0.4], 5, "duplicated"),    # a repeat, then a step back: the repeat (earlier) is named
    ([0.3, 0.25, 0.25, 0.4], 5, "decreasing"),   # a step back, then a repeat: the step back
    ([0.2, 0.3, 0.4, 0.5], 4, "duplicated"),     # across the block boundary: row 4 repeats row 3's time
])
def test_estimate_block_check_names_the_earliest_bad_time_step_with_its_file_wide_row(t2, row, what):
    """``selfsense estimate`` checks a log block by block: the first time step that does not increase is named
    with its 1-based row in the file, also where it spans two blocks."""
    from selfsense.cli.estimate import _checked
    from selfsense.io.errors import ContractError

    cols = {c: c for c in ("t", "u_cmd", "v_shunt", "relay")}
    blocks = [{"t": np.array([0.0, 0.1, 0.2]), "u_cmd": np.zeros(3), "v_shunt": np.zeros(3), "relay": np.ones(3)},
              {"t": np.array(t2), "u_cmd": np.zeros(4), "v_shunt": np.zeros(4), "relay": np.zeros(4)}]
    it = _checked(Path("log.parquet"), cols, iter(blocks))
    next(it)
    with pytest.raises(ContractError) as e:
        next(it)
    msg = str(e.value)
    assert f"row {row}" in msg and what in msg and "log.parquet" in msg, msg
