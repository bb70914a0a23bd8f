"""Excitation check and acquisition-protocol proposal (docs/gap.md)."""
import pytest

from selfsense.gap.blindsim import simulate_family_case
from selfsense.gap.protocol import ELEMENTS, excitation_check, proposal


@pytest.fixture(scope="module")
def bench_case():
    """An effect-free blind-check case (the diagnostic protocol of selfsense.gap.blindsim.device_scenario)."""
    return simulate_family_case("preisach", 5, {}, 5)


def test_benchmark_scenarios_contain_the_whole_protocol(bench_case):
    trials, meta, _ = bench_case
    chk = excitation_check(trials, meta)
    assert chk["missing"] == []
    assert "cal_protocol" in chk["present"]["symmetric_steps"]
    assert "cal_protocol -> val_repeat" in chk["present"]["rest_then_repeat"]
    assert "every protocol element" in proposal(chk)


def test_sine_only_data_get_a_protocol_proposal(bench_case):
    trials, meta, _ = bench_case
    sines = meta[meta.index.isin(["cal_free", "val_blocked"])]   # sines only: no holds at high V, no steps
    chk = excitation_check(trials, sines)
    assert {"hold_high_V", "symmetric_steps", "rest_then_repeat"} <= set(chk["missing"])
    text = proposal(chk)
    for k in chk["missing"]:
        assert ELEMENTS[k].split(" (")[-1].rstrip(")") in text
    assert "symmetric_steps" not in chk["present"]
