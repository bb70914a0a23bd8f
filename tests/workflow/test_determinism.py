"""The cross-machine tolerances of the determinism contract (selfsense.determinism, docs/reproducibility.md)
accept last-bit and adjacent-ADC-code differences and nothing larger."""
import numpy as np
import pandas as pd

from selfsense.determinism import (DAQ_MAX_FRACTION, EFFECT_RTOL, TRUTH_RTOL, compare_daq_log, compare_tree,
                                   compare_truth)

LSB = 20.0 / 2**16  # one code of a 16-bit +-10 V ADC


def _log(n=4000, seed=0):
    rng = np.random.default_rng(seed)
    codes = np.round(rng.normal(0.0, 3000.0, n))
    return pd.DataFrame({"t": np.arange(n) * 1e-3, "v_shunt": codes * LSB, "relay": (np.arange(n) < 100).astype("int8")})


def test_one_ulp_in_a_json_number_is_accepted_a_changed_word_is_not():
    ref = {"effects": {"rate.amplifier": 24.145264063412498}, "sim_seed": 7, "estimator": "sensing_ri"}
    got = {"effects": {"rate.amplifier": 24.145264063412494}, "sim_seed": 7, "estimator": "sensing_ri"}
    assert compare_tree(got, ref) == []
    assert compare_tree(dict(got, sim_seed=8), ref) == ["sim_seed: 8 != 7"]
    assert compare_tree(dict(got, estimator="sensing"), ref) == ["estimator: 'sensing' != 'sensing_ri'"]
    far = {"effects": {"rate.amplifier": 24.1453}, "sim_seed": 7, "estimator": "sensing_ri"}
    assert len(compare_tree(far, ref)) == 1


def test_daq_log_allows_a_few_adjacent_codes_only():
    ref = _log()
    got = ref.copy()
    k = int(DAQ_MAX_FRACTION * len(ref))  # the allowed number of samples one code apart
    got.loc[got.index[:k], "v_shunt"] += LSB
    assert compare_daq_log(got, ref) == []
    two = ref.copy()
    two.loc[two.index[5], "v_shunt"] += 2 * LSB
    assert "exceeds 1 step" in " ".join(compare_daq_log(two, ref))
    many = ref.copy()
    many.loc[many.index[: 2 * k + 2], "v_shunt"] += LSB
    assert "samples differ" in " ".join(compare_daq_log(many, ref))
    relay = ref.copy()
    relay.loc[relay.index[0], "relay"] = 0
    assert compare_daq_log(relay, ref) == ["log.relay: non-float values differ"]


def test_truth_tolerance_is_relative_to_the_signal_range():
    t = np.linspace(0.0, 1.0, 1000)
    ref = pd.DataFrame({"q": 3e-4 * np.sin(t), "dx_ref": 5e-6 * np.sin(t), "effect__creep": 1e-9 * t})
    ok = ref.copy()
    ok["q"] += 0.5 * TRUTH_RTOL * 3e-4 * np.sin(t) ** 2
    ok["effect__creep"] += 0.5 * EFFECT_RTOL * 5e-6   # an effect column is scaled by dx_ref, not by itself
    assert compare_truth(ok, ref) == []
    bad = ref.copy()
    bad["dx_ref"] *= 1 + 10 * TRUTH_RTOL
    assert [m.split(":")[0] for m in compare_truth(bad, ref)] == ["truth.dx_ref"]
