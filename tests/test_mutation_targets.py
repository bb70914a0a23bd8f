"""The mutation check (tests/mutation_check.py, docs/testing.md) cannot rot: every mutated line still exists exactly
once in the source, and every test it names exists."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("mutation_check", ROOT / "tests" / "mutation_check.py")
mc = importlib.util.module_from_spec(spec)
sys.modules["mutation_check"] = mc   # dataclasses resolve annotations through sys.modules
spec.loader.exec_module(mc)


@pytest.mark.parametrize("m", mc.MUTANTS, ids=lambda m: m.name[:40])
def test_mutant_applies_once_and_names_existing_tests(m):
    src = (ROOT / "src" / "selfsense" / m.file).read_text()
    assert src.count(m.old) == 1, f"{m.file}: the mutated line occurs {src.count(m.old)} times"
    assert m.new != m.old
    for t in m.tests:
        assert (ROOT / t.split("::")[0]).exists(), t


def test_docs_list_every_mutant():
    doc = (ROOT / "docs" / "testing.md").read_text()
    assert "python tests/mutation_check.py" in doc
    for m in mc.MUTANTS:
        assert f"`{m.file}`" in doc or m.file in doc, m.file
