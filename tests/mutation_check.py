#!/usr/bin/env python
"""Mutation check: five deliberate defects, each of which the test suite must catch.

    python tests/mutation_check.py              # all five mutants (about 5 min on 2 cores)
    python tests/mutation_check.py --only 1,3   # some of them

For each mutant the source tree ``src/`` is copied to a temporary folder, one line is changed there (never in the
working tree), and the tests that claim to guard that behaviour run against the copy (``PYTHONPATH`` puts the
copy first). A mutant is *killed* when at least one of those tests fails; the script exits 1 if any survives. The
list, the tests that kill each mutant and the measured result are in docs/testing.md. The file is not named
``test_*.py``, so pytest does not collect it.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Mutant:
    name: str
    file: str        # relative to src/selfsense
    old: str         # exact text to replace (must occur once)
    new: str
    tests: tuple     # pytest node ids / files that must fail


MUTANTS = [
    Mutant("sign flip in eq. (52): dx = A1 Q - A2 V_p",
           "sensing/core.py", "    return a * q + b * vp + c\n", "    return a * q - b * vp + c\n",
           ("tests/sensing/test_estimator.py", "tests/pipeline/test_accuracy_pinned.py")),
    Mutant("leakage gate off: the holds' leakage never adopted",
           "sensing/estimator.py",
           "    return bool(hold_supported and cv_with <= LEAK_HOLD_MAX_CV_RATIO * cv_without)\n",
           "    return False\n",
           ("tests/chain/test_chain_members.py",)),
    Mutant("limiting off: estimates never clipped to the calibrated ranges",
           "signals/offset.py", "    return np.clip(np.asarray(x, dtype=np.float64), lo, hi)\n",
           "    return np.asarray(x, dtype=np.float64)\n",
           ("tests/sensing/test_streaming.py", "tests/signals")),
    Mutant("wrong charge integration constant: q(t) = integral + 0.1 uC",
           "signals/charge.py", "    q = c - base\n", "    q = c - base + 1e-7\n",
           ("tests/signals", "tests/sensing/test_streaming.py")),
    Mutant("a gap member never accepted",
           "gap/stages.py", "        if not ratio > 1.0:\n            break\n", "        break\n",
           ("tests/gap/test_stages.py",)),
]


def run_mutant(m: Mutant, workers: int) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="selfsense-mutant-"))
    try:
        shutil.copytree(ROOT / "src", tmp / "src", ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        f = tmp / "src" / "selfsense" / m.file
        text = f.read_text()
        if text.count(m.old) != 1:
            return {"mutant": m.name, "status": f"NOT APPLIED: the line was found {text.count(m.old)} times in {m.file}"}
        f.write_text(text.replace(m.old, m.new))
        env = dict(os.environ, PYTHONPATH=str(tmp / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""),
                   MPLBACKEND="Agg", NUMBA_CACHE_DIR=str(tmp / "numba-cache"))
        cmd = [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", *m.tests]
        if workers > 1:
            cmd += ["-n", str(workers)]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
        dt = time.perf_counter() - t0
        # the copy must really be the code under test
        check = subprocess.run([sys.executable, "-c", "import selfsense; print(selfsense.__file__)"], env=env,
                               capture_output=True, text=True, cwd=ROOT).stdout.strip()
        if not check.startswith(str(tmp)):
            return {"mutant": m.name, "status": f"NOT RUN: selfsense imported from {check}, not the mutated copy"}
        failed = [ln for ln in proc.stdout.splitlines() if ln.startswith("FAILED") or ln.startswith("ERROR")]
        status = "killed" if proc.returncode != 0 else "SURVIVED"
        return {"mutant": m.name, "status": status, "seconds": dt, "by": failed[:3], "tests": " ".join(m.tests)}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="", help="comma-separated mutant numbers (1-5)")
    ap.add_argument("--workers", type=int, default=2, help="pytest-xdist workers per mutant (default 2)")
    a = ap.parse_args(argv)
    pick = [int(x) for x in a.only.split(",") if x.strip()] or list(range(1, len(MUTANTS) + 1))
    results = []
    for i in pick:
        r = run_mutant(MUTANTS[i - 1], a.workers)
        results.append(r)
        print(f"{i}. {r['mutant']}: {r['status']}" + (f" ({r['seconds']:.0f} s; {r['by'][0]})" if r.get("by") else
                                                      f" ({r.get('seconds', 0):.0f} s)"), flush=True)
    survived = [r for r in results if r["status"] != "killed"]
    print(f"{len(results) - len(survived)} of {len(results)} mutants killed")
    return 1 if survived else 0


if __name__ == "__main__":
    sys.exit(main())
