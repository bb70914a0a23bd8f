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
