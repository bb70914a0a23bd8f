"""One source for every quoted figure: the README's and the docs' figure tables are generated from the committed
benchmark outputs by ``benchmarks/figures.py``, and no figure of the measured kinds is written by hand elsewhere."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "figures.py"
BLOCK = re.compile(r"<!-- figures:([a-z_]+) -->\n.*?<!-- /figures:\1 -->", re.S)
#: measured figures that must only appear inside generated blocks (speed, memory, pipeline time)
HAND_WRITTEN = [
    re.compile(r"\d[\d,.]*\s*M samples/s"),
    re.compile(r"\d[\d.]*\s*(?:us|µs)\s*(?:/|per)\s*sample"),
    re.compile(r"\d[\d.]*\s*s wall"),
    re.compile(r"\d[\d.]*\s*s by Snakemake's clock"),
    re.compile(r"peak RSS (?:of )?\d"),
]


def _pages():
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _check(root: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), "--check", "--root", str(root)], capture_output=True,
                          text=True)


def test_readme_docs_and_figures_md_agree_with_the_benchmark_outputs():
    r = _check(ROOT)
    assert r.returncode == 0, r.stderr


def test_every_figure_block_is_filled_and_the_readme_quotes_all_groups():
    text = (ROOT / "README.md").read_text()
    assert "<!-- figures:all -->" in text
    for page in _pages():
        for m in BLOCK.finditer(page.read_text()):
            assert "| figure | measured | target | status |" in m.group(0), f"{page.name}: empty block {m.group(1)}"


def test_the_readme_shows_first_contact_and_current_rows_the_docs_every_scoring():
    """The README's table keeps each benchmark's first contact and its current-code score; the scorings in between
    are in benchmarks/FIGURES.md and the docs page of the benchmark, never dropped from both."""
    readme = BLOCK.search((ROOT / "README.md").read_text()).group(0)
    docs = (ROOT / "docs" / "cross_device.md").read_text()
    figures_md = (ROOT / "benchmarks" / "FIGURES.md").read_text()
    first = "whole-device randomisation, thesis calibration, first contact"
    between = "whole-device randomisation, thesis calibration, with the hold rows"
    assert first in readme and first in docs
    assert between not in readme and between in docs and between in figures_md
    n = int(re.search(r"(\d+) rows of scorings in between", readme).group(1))
    rows = lambda text: {x.split(" | ")[0] for x in text.splitlines() if x.startswith("| ") and " | " in x}  # noqa: E731
    assert len(rows(figures_md) - rows(readme)) >= n > 0


@pytest.mark.parametrize("page", _pages(), ids=lambda p: p.name)
def test_no_measured_figure_is_written_by_hand_outside_the_generated_blocks(page):
    outside = BLOCK.sub("", page.read_text())
    for pat in HAND_WRITTEN:
        m = pat.search(outside)
        assert m is None, (f"{page.relative_to(ROOT)}: {m.group(0)!r} is a measured figure written by hand; quote it "
                           "from a generated block (benchmarks/figures.py)")


def test_check_fails_when_a_benchmark_output_changes(tmp_path):
    """The consistency check is not vacuous: a changed number in RESULTS.json makes the README stale."""
    for rel in ("README.md", "docs", "benchmarks"):
        src = ROOT / rel
        (shutil.copytree if src.is_dir() else shutil.copy)(src, tmp_path / rel)
    assert _check(tmp_path).returncode == 0
    res = json.loads((tmp_path / "benchmarks" / "RESULTS.json").read_text())
    res["b"]["step_us"] = res["b"]["step_us"] * 10 + 1.0
    (tmp_path / "benchmarks" / "RESULTS.json").write_text(json.dumps(res))
    r = _check(tmp_path)
    assert r.returncode == 1
    assert "README.md" in r.stderr and "benchmarks/FIGURES.md" in r.stderr


def test_check_fails_when_the_report_screenshot_is_of_another_default(tmp_path):
    for rel in ("README.md", "docs", "benchmarks"):
        src = ROOT / rel
        (shutil.copytree if src.is_dir() else shutil.copy)(src, tmp_path / rel)
    side = tmp_path / "docs" / "img" / "report_tweezer_sim_top.json"
    side.write_text(json.dumps({"table3_percent_of_range": {"displacement": "9.05 %", "force": "10.78 %"}}))
    r = _check(tmp_path)
    assert r.returncode == 1 and "report_tweezer_sim_top.png" in r.stderr
