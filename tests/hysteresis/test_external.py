"""Real measured data (the external data folder, PROVENANCE.md): the H model selected by blocked CV on the fit record
must beat a straight line and the plain 10-operator PI out of sample, with no solver failure."""

from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[2].parent / "shared"
DATA = SHARED / "data" / "external"


@pytest.mark.slow
def test_selected_h_beats_line_and_pi10_out_of_sample_on_piezo_records():
    if not (DATA / "smart_hysteresis").is_dir() or not (DATA / "danny_preisach").is_dir():
        pytest.skip(f"external data not found at {DATA} (../shared absent in this checkout)")
    from selfsense.hysteresis.external import run

    rows = {r["key"]: r for r in run(DATA)}
    for key in ("smart", "sine50_1", "prbn_1"):
        r = rows[key]
        assert r["h_selected"][0] < r["linear"][0], r["pair"]
        assert r["h_selected"][0] < r["baseline_pi10"][0], r["pair"]
        assert r["h_selected"][0] < r["provenance_baseline"][0], r["pair"]
        # our NNLS baseline reproduces PROVENANCE's within 15 % (RMS): the comparison is like for like
        assert r["baseline_pi10"][0] == pytest.approx(r["provenance_baseline"][0], rel=0.15), r["pair"]
        assert not any("failed" in c["status"] for c in r["selection"] if c["kind"] != "modified_pi"), r["pair"]


def test_fit_external_accepts_any_record_pair(tmp_path):
    """A user-named pair of CSV records (FILE:X:Y[:T]) is fitted and scored; a missing column is one clear error."""
    import numpy as np
    import pandas as pd

    from selfsense.hysteresis.external import main
    from selfsense.hysteresis.operators import play_operator

    t = np.arange(4000) * 1e-3
    x = 100 * np.sin(2 * np.pi * 1.0 * t) * np.linspace(1, 0.4, t.size)
    y = 0.02 * x + 0.3 * play_operator(x, [13.0])[:, 0] + 0.8 * np.tanh(x / 40)   # not in the PI-10 class
    pd.DataFrame({"time": t, "volt": x, "disp": y}).to_csv(tmp_path / "a.csv", index=False)
    out = tmp_path / "pair.md"
    assert main(["--fit", f"{tmp_path / 'a.csv'}:volt:disp:time", "--out", str(out)]) == 0
    assert "1st half -> 2nd half" in out.read_text()
    assert main(["--fit", f"{tmp_path / 'a.csv'}:volt:nope"]) == 2
