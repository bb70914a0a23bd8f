"""Smoke run of the real Snakefile on data/raw/sample, twice, with bit-identical outputs (reproducibility)."""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "data" / "raw" / "sample"


def _run_pipeline(workdir: Path) -> None:
    workdir.mkdir(parents=True, exist_ok=True)
    cfg = yaml.safe_load((ROOT / "config.yaml").read_text())
    cfg["datasets"] = ["sample"]
    cfg["raw_dir"] = str(ROOT / "data" / "raw")
    cfg["results_dir"] = "results"
    (workdir / "config.yaml").write_text(yaml.safe_dump(cfg))
    env = dict(os.environ, MPLBACKEND="Agg")
    proc = subprocess.run(
        [sys.executable, "-m", "snakemake", "--cores", "2", "--snakefile", str(ROOT / "Snakefile"),
         "--directory", str(workdir), "--configfile", str(workdir / "config.yaml"), "--quiet", "all"],
        capture_output=True, text=True, env=env, timeout=900,
    )
    assert proc.returncode == 0, f"snakemake failed:\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}"


def _hashes(results: Path) -> dict[str, str]:
    out = {}
    for p in sorted(results.rglob("*")):
        if p.is_file() and "benchmarks" not in p.parts and "logs" not in p.parts:
            out[str(p.relative_to(results))] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def _first_difference(a: Path, b: Path) -> str:
    """How two files differ: their sizes and the bytes around the first one that differs (a hash says only that)."""
    x, y = a.read_bytes(), b.read_bytes()
    i = next((k for k, (p, q) in enumerate(zip(x, y)) if p != q), min(len(x), len(y)))
    lo = max(0, i - 60)
    return f"{len(x)} vs {len(y)} bytes, first difference at byte {i}: {x[lo:i + 60]!r} vs {y[lo:i + 60]!r}"


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    if not SAMPLE.exists():
        pytest.fail("data/raw/sample is missing: the bundled sample dataset must be committed")
    raw_before = {str(p): p.stat().st_mtime_ns for p in SAMPLE.rglob("*")}
    a = tmp_path_factory.mktemp("run_a")
    b = tmp_path_factory.mktemp("run_b")
    _run_pipeline(a)
    _run_pipeline(b)
    raw_after = {str(p): p.stat().st_mtime_ns for p in SAMPLE.rglob("*")}
    assert raw_before == raw_after, "data/raw was modified by the pipeline"
    return a / "results" / "sample", b / "results" / "sample"


def test_contract_outputs_exist(two_runs):
    res, _ = two_runs
    t3 = pd.read_csv(res / "tables" / "table3.csv")
    assert list(t3["measurement"]) == ["displacement", "force"]
    for col in ("mean_abs_error", "percent_of_range", "n_trials"):
        assert col in t3.columns
    assert (t3["n_trials"] > 0).all()
    pt = pd.read_csv(res / "tables" / "per_trial.csv")
    assert {"trial", "measurement", "mean_abs_error", "percent_of_range", "role"} <= set(pt.columns)
    for p in (res / "estimates").glob("*.parquet"):
        df = pd.read_parquet(p)
        assert list(df.columns) == ["t", "dx_hat", "f_hat", "dx_ref", "f_ref"]
        assert df[["dx_hat", "f_hat"]].notna().all().all(), f"NaN reached estimate {p.name}"
    assert (res / "report.html").stat().st_size > 10_000
    # the drive coverage of the calibration: one row per trial in trials.csv order, the calibration trials define it
    cov = pd.read_csv(res / "tables" / "coverage.csv", keep_default_na=False)
    assert list(cov["trial"]) == list(pd.read_csv(SAMPLE / "trials.csv")["trial"])
    assert (cov.loc[cov["role"] == "calibration", "lacks"] == "").all()
    assert "Drive coverage of the calibration" in (res / "report.html").read_text()
    model = json.loads((res / "model" / "sensing.json").read_text())
    assert {"A1", "A2", "A3"} <= set(model["coef"])
    # the charge resolution of every trial (reference-free): the sample's 16-bit shunt channel is dithered by its
    # noise, so the offset's statistical error is all that is left (nC, not the uC of an undithered channel)
    cres = model["fit_report"]["charge_resolution"]
    assert set(cres["trials"]) == set(pd.read_csv(SAMPLE / "trials.csv")["trial"])
    assert not cres["limited"] and "resolves the charge" in cres["note"]
    for d in cres["trials"].values():
        assert d["dithered"] and d["step_v"] > 0 and 0.0 < d["sigma_q_end_c"] < 1e-7
    for stem in ("fig17_voltage_charge", "fig21_h_calibration", "fig25-30_displacement_trials", "fig31-36_force_trials"):
        assert (res / "figures" / f"{stem}.png").exists() and (res / "figures" / f"{stem}.pdf").exists()


def test_table3_of_the_smoke_run_is_the_measured_accuracy(two_runs, sample_table3_pins):
    """The real Snakefile's Table 3 on the sample equals the measured figures within the cross-machine tolerance
    (tests/conftest.py), so a 2x regression of the pipeline fails here too."""
    res, _ = two_runs
    t3 = pd.read_csv(res / "tables" / "table3.csv").set_index("measurement")
    for m, (pct, tol) in sample_table3_pins.items():
        assert t3.loc[m, "percent_of_range"] == pytest.approx(pct, abs=tol), (m, t3.loc[m, "percent_of_range"])


def test_estimates_are_physical(two_runs):
    """Estimates lie in the physical range after limiting."""
    res, _ = two_runs

    ranges = json.loads((res / "model" / "sensing.json").read_text())["ranges"]
    # limits from the calibration references: force >= 0; displacement >= the smallest closing seen there
    # (remanence may open the tip slightly beyond rest), which is within a few % of the stroke below 0
    lo, hi = ranges["dx"]
    assert -0.05 * hi <= lo <= 0.0
    for p in (res / "estimates").glob("*.parquet"):
        df = pd.read_parquet(p)
        assert (df["dx_hat"] >= lo).all() and (df["dx_hat"] <= hi).all() and (df["f_hat"] >= 0).all()


def test_bit_identical_reruns(two_runs):
    """Two runs of the real Snakefile on the sample give the same files with the same bytes. On a failure the message
    names every differing file with its first differing bytes, and both runs' folders are kept by pytest (basetemp),
    so that a rare failure leaves its evidence."""
    a, b = two_runs
    ha, hb = _hashes(a), _hashes(b)
    assert ha.keys() == hb.keys(), f"files in one run only: {sorted(ha.keys() ^ hb.keys())}"
    diff = {k: _first_difference(a / k, b / k) for k in ha if ha[k] != hb[k]}
    assert not diff, (f"outputs differ between two identical runs ({a} and {b}):\n"
                      + "\n".join(f"{k}: {d}" for k, d in diff.items()))


def test_first_difference_locates_the_differing_bytes(tmp_path):
    """The rerun test's failure message points at the first differing byte and reports both sizes."""
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_bytes(b"git commit: 0123abcd\n")
    b.write_bytes(b"git commit: 0123abcd + local changes\n")
    msg = _first_difference(a, b)
    assert msg.startswith("21 vs 37 bytes, first difference at byte 20:")
    a.write_bytes(b"x = 1.0000000000000002")
    b.write_bytes(b"x = 1.0000000000000004")
    assert "first difference at byte 21:" in _first_difference(a, b)


def test_report_in_headless_chromium(two_runs):
    """The smoke run's report.html rendered by headless Chromium: every image loads, no JavaScript or console error,
    no raw Markdown or JSON in the visible text. Screenshots are kept as test artefacts
    ($SELFSENSE_TEST_ARTIFACTS, default test-artifacts/browser/)."""
    from selfsense.report.browser import check_report, chromium, screenshot

    if chromium() is None:
        pytest.skip("Chromium is not installed (Debian: apt-get install -y chromium); the browser test needs it")
    res, _ = two_runs
    chk = check_report(res / "report.html")
    figures = len(json.loads((res / "figures" / "captions.json").read_text()))
    gap_pngs = len(list((res / "gap").glob("*.png")))
    assert chk.n_images == figures + gap_pngs and chk.n_images >= 8
    assert chk.broken_images == [], chk.broken_images
    assert chk.errors == [] and chk.console == [], (chk.errors, chk.console)
    assert chk.raw_markup == [], chk.raw_markup
    for heading in ("Provenance", "Accuracy (thesis Table 3 / paper Table II)", "Calibrated model", "Figures",
                    "Sim-to-real gap diagnostic"):
        assert heading in chk.text
    out = Path(os.environ.get("SELFSENSE_TEST_ARTIFACTS", ROOT / "test-artifacts")) / "browser"
    for name, height in (("report_top.png", 2400), ("report_full.png", 16000)):
        png = screenshot(res / "report.html", out / name, height=height)
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_snakemake_report_holds_every_table_and_figure_with_its_caption(two_runs, tmp_path):
    """`snakemake --report report.zip` (Snakemake's own report) contains every figure PNG of the run, the tables
    and the gap diagnostic's files, each with its caption from workflow/report/*.rst."""
    import zipfile

    res, _ = two_runs
    workdir = res.parents[1]
    out = tmp_path / "report.zip"
    proc = subprocess.run(
        [sys.executable, "-m", "snakemake", "--snakefile", str(ROOT / "Snakefile"), "--directory", str(workdir),
         "--configfile", str(workdir / "config.yaml"), "--report", str(out)],
        capture_output=True, text=True, env=dict(os.environ, MPLBACKEND="Agg"), timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    names = {Path(n).name for n in zipfile.ZipFile(out).namelist()}
    figures = {p.name for p in (res / "figures").glob("*.png")}
    assert len(figures) >= 4 and figures <= names, figures - names
    assert {"table3.csv", "per_trial.csv", "coverage.csv", "modes.csv", "report.html"} <= names
    if (res / "gap").is_dir():
        assert {p.name for p in (res / "gap").glob("*.png")} | {"stages.csv", "effects.csv", "candidates.csv"} <= names
    page = zipfile.ZipFile(out).read("report/report.html").decode()
    for phrase in ("Thesis Table 3 / paper Table II", "regenerates thesis Fig. 17", "regenerates thesis Fig. 21"):
        assert phrase in page, phrase
