"""The seed / case lists of the benchmark scripts (``benchmarks/_args.py``, shared by six of them) and their BLAS pinning."""
import argparse
import importlib.util
import sys
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


def _tip_pool():
    s = importlib.util.spec_from_file_location("tip_pool", ROOT / "benchmarks" / "tip_pool.py")
    m = importlib.util.module_from_spec(s)
    s.loader.exec_module(m)
    return m


def test_tip_pool_writes_the_committed_tier_and_refuses_parts_that_do_not_make_one(tmp_path):
    """``benchmarks/tip_pool.py`` pools the parts of one seed into the records and scores one campaign of that many
    cases writes: the committed 160-case tier is its output from the committed 80-case first contact and cases
    80-159; records of two seeds, a case twice or a gap in the cases are refused."""
    import gzip
    import json

    pool = _tip_pool()
    tier = ROOT / "benchmarks" / "gap_tip" / "seed_20261217_160"
    recs = [json.loads(x) for x in gzip.open(tier / "tip_cases.jsonl.gz", "rt")]
    first = ROOT / "benchmarks" / "gap_tip" / "seed_20261217" / "tip_cases.jsonl.gz"
    assert [json.loads(x) for x in gzip.open(first, "rt")] == recs[:80]

    def part(name, rows):
        p = tmp_path / name
        with gzip.open(p, "wt") as fh:
            fh.writelines(json.dumps(r) + "\n" for r in rows)
        return str(p)

    rest = part("rest.jsonl.gz", recs[80:])
    out = tmp_path / "pooled"
    cmd = json.loads((tier / "tip_scores.json").read_text())
    assert pool.main(["--records", str(first), rest, "--out", str(out), "--command", "x"]) == 0
    got = json.loads((out / "tip_scores.json").read_text())
    assert got == cmd
    assert (out / "tip_cases.jsonl.gz").read_bytes() == (tier / "tip_cases.jsonl.gz").read_bytes()
    with pytest.raises(SystemExit, match="once each"):
        pool.main(["--records", str(first), part("gap.jsonl.gz", recs[81:]), "--out", str(out), "--command", "x"])
    with pytest.raises(SystemExit, match="once each"):
        pool.main(["--records", str(first), part("twice.jsonl.gz", recs[79:]), "--out", str(out), "--command", "x"])
    other = [dict(r, seed=1) for r in recs[80:]]
    with pytest.raises(SystemExit, match="several seeds"):
        pool.main(["--records", str(first), part("seed.jsonl.gz", other), "--out", str(out), "--command", "x"])


def _fake_tip_case(args):
    i, seed = args
    if i == 13:
        raise ValueError("case 13 fails")
    return {"case": i, "seed": seed, "made": "now"}


def test_tip_cases_keeps_finished_cases_and_resumes_without_running_them_again(tmp_path, monkeypatch):
    """``benchmarks/tip_cases.py`` appends each finished case to ``<out>.partial.jsonl`` at once; a run started again
    takes the cases of its seed found there (a line cut off by the stop is run again) and runs only the others."""
    import json

    spec = importlib.util.spec_from_file_location("tip_cases", ROOT / "benchmarks" / "tip_cases.py")
    tc = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "tip_cases", tc)
    spec.loader.exec_module(tc)
    monkeypatch.setattr(tc, "_one", _fake_tip_case)
    partial = tmp_path / "part.partial.jsonl"
    kept = [{"case": 0, "seed": 7, "made": "before"}, {"case": 1, "seed": 8, "made": "before"}]
    partial.write_text("".join(json.dumps(r) + "\n" for r in kept) + '{"case": 2, "se')
    recs = tc._run_cases([0, 1, 2], 7, 2, partial)
    assert [(r["case"], r["made"]) for r in recs] == [(0, "before"), (1, "now"), (2, "now")]
    lines = partial.read_text().splitlines()
    assert lines[2] == '{"case": 2, "se'
    assert sorted(json.loads(x)["case"] for x in lines[3:]) == [1, 2]   # only the missing cases appended
    assert tc._run_cases([0, 1, 2], 7, 2, partial) == recs and len(partial.read_text().splitlines()) == 5
    # a failed case: the others are kept before the error is raised; a case given twice runs once
    with pytest.raises(RuntimeError, match=r"1 case\(s\) failed \(13\)"):
        tc._run_cases([4, 13, 5, 5], 7, 2, partial)
    lines = partial.read_text().splitlines()
    assert sorted(json.loads(x)["case"] for x in lines[5:]) == [4, 5]


def test_every_script_that_runs_cases_in_workers_pins_one_blas_thread():
    """A script that fits estimators in worker processes runs them with one BLAS thread, as ``selfsense gap blind``
    does (``selfsense.determinism.single_thread_blas`` or the thread variables set before NumPy is imported):
    otherwise two workers on two cores each start a second BLAS thread, slower (``tip_cases.py --seed 20261219 --cases
    20,23 --jobs 2``: 52.7 s wall unpinned, 44.7 s pinned), and the records differ from the command's in the last
    bits."""
    unpinned = []
    for p in sorted((ROOT / "benchmarks").glob("*.py")):
        text = p.read_text()
        runs_cases = "ProcessPoolExecutor" in text or "run_tip_case" in text or "fork_map" in text
        pinned = "single_thread_blas()" in text or 'os.environ.setdefault(_v, "1")' in text
        if runs_cases and not pinned and p.name not in ("tip_pool.py", "_args.py"):
            unpinned.append(p.name)
    assert unpinned == []



def test_compare_benches_takes_the_first_run_from_several_folders(tmp_path):
    """compare_benches.py --first-also: a device that several folders of the first run hold is taken from one where it
    was scored (status ok), the later folder where more than one did; the order of the folders decides nothing else."""
    import pandas as pd

    spec_c = importlib.util.spec_from_file_location("compare_benches", ROOT / "benchmarks" / "compare_benches.py")
    cb = importlib.util.module_from_spec(spec_c)
    spec_c.loader.exec_module(cb)

    def write(name, rows):
        d = tmp_path / name
        d.mkdir()
        pd.DataFrame(rows, columns=["family", "preset", "seed", "status", "displacement_pct", "force_pct",
                                    "charge_resolution_dx_pct"]).to_csv(d / "records.csv", index=False)
        return d

    a = write("a", [("bw", "clean", 1, "ok", 4.0, 2.0, 0.0), ("bw", "clean", 2, "invalid_dataset", None, None, None)])
    b = write("b", [("bw", "clean", 2, "ok", 6.0, 3.0, 0.5), ("bw", "clean", 1, "ok", 5.0, 2.5, 0.0)])
    c = write("c", [("bw", "clean", 2, "failed", None, None, None)])
    new = write("new", [("bw", "clean", 1, "ok", 3.0, 1.0, 0.0), ("bw", "clean", 2, "ok", 7.0, 4.0, 0.5)])
    m = cb.compare([a, b, c], new).set_index("seed")
    assert m.loc[1, "displacement_pct_base"] == 5.0      # both scored it: the later folder
    assert m.loc[2, "displacement_pct_base"] == 6.0      # only b scored it, c (later) failed
    assert m.loc[2, "displacement_pct_other"] == 7.0 and not m.loc[2, "dithered"]
    assert cb.compare(a, new).set_index("seed").loc[1, "displacement_pct_base"] == 4.0   # one folder, as before


def test_one_per_device_keeps_the_scored_record_of_the_latest_part():
    """benchmarks/_records.py (compare_benches --first-also, adc_cost --native): one row per device; a scored record
    beats a later failed one, the later of two scored ones wins, a part without a status column counts as scored, and
    no parts is an error rather than an empty table."""
    import pandas as pd
    import pytest

    spec_r = importlib.util.spec_from_file_location("bench_records", ROOT / "benchmarks" / "_records.py")
    rec = importlib.util.module_from_spec(spec_r)
    spec_r.loader.exec_module(rec)
    cols = ["family", "preset", "seed", "status", "x"]
    p1 = pd.DataFrame([("gpi", "drift", 3, "ok", 1.0), ("gpi", "drift", 4, "ok", 2.0),
                       ("gpi", "clean", 3, "failed", 9.0)], columns=cols)
    p2 = pd.DataFrame([("gpi", "drift", 3, "failed", 8.0), ("gpi", "drift", 4, "ok", 3.0)], columns=cols)
    p3 = pd.DataFrame([("gpi", "clean", 3, 5.0)], columns=["family", "preset", "seed", "x"])   # no status column
    got = rec.one_per_device([p1, p2, p3]).set_index(["preset", "seed"])["x"]
    assert len(got) == 3 and list(rec.one_per_device([p1, p2, p3]).columns) == cols
    assert got[("drift", 3)] == 1.0     # the later part failed it: the scored record stays
    assert got[("drift", 4)] == 3.0     # both scored it: the later part
    assert got[("clean", 3)] == 5.0     # scored (no status column) beats the earlier failure
    only_failed = rec.one_per_device([p2.iloc[[0]], p1.iloc[[2]]])
    assert sorted(only_failed["x"]) == [8.0, 9.0]   # different devices, each kept though none was scored
    with pytest.raises(ValueError, match="no records"):
        rec.one_per_device([])
