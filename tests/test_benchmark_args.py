"""The seed / case lists of the benchmark scripts (``benchmarks/_args.py``, shared by six of them)."""
import argparse
import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("bench_args", ROOT / "benchmarks" / "_args.py")
bench_args = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench_args)


def test_lists_and_inclusive_ranges_in_the_order_given():
    assert bench_args.int_ranges("0-4,7,10-11") == [0, 1, 2, 3, 4, 7, 10, 11]
    assert bench_args.int_ranges("12") == [12]
    assert bench_args.int_ranges("5-5, 3") == [5, 3]


@pytest.mark.parametrize("bad, part", [("0-x", "0-x"), ("1,,2", ""), ("9-3", "9-3"), ("a", "a")])
def test_a_malformed_part_is_named(bad, part):
    with pytest.raises(argparse.ArgumentTypeError, match=repr(part)):
        bench_args.int_ranges(bad)


def test_no_benchmark_script_keeps_its_own_copy():
    """The parser lived in six scripts before; one copy is the contract."""
    copies = [p.name for p in (ROOT / "benchmarks").glob("*.py")
              if p.name != "_args.py" and 'part.partition("-")' in p.read_text()]
    assert copies == []


def test_stage_chain_refuses_to_mix_forced_members_into_a_folder(tmp_path):
    """A folder of stage_chain.py holds one estimator configuration (its summary and the README's medians read every
    record): a run with other --members stops before fitting anything, naming the folder's members."""
    import json
    import subprocess
    import sys

    rec = {"family": "preisach", "preset": "clean", "seed": 0, "members": {"offset_drift": "on"}}
    (tmp_path / "records.jsonl").write_text(json.dumps(rec) + "\n")
    p = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "stage_chain.py"), "devices", "--families",
                        "preisach", "--presets", "clean", "--seeds", "0", "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode != 0
    assert '--members {"offset_drift": "on"}' in p.stderr and "another --out" in p.stderr
    assert (tmp_path / "records.jsonl").read_text() == json.dumps(rec) + "\n"
