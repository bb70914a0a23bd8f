"""Suite-wide: a summary of the skipped tests at the end of every run, grouped by reason, so that a run without
Chromium, the external measurements or the SLURM opt-in says how much it did not test."""
from __future__ import annotations

from collections import Counter



def pytest_terminal_summary(terminalreporter, exitstatus, config):
    skipped = terminalreporter.stats.get("skipped", [])
    warned = [r for r in terminalreporter.stats.get("warnings", []) if "SLURM NOT USED" in str(r.message)]
    if not skipped and not warned:
        return
    reasons = Counter()
    for rep in skipped:
        longrepr = rep.longrepr
        reason = longrepr[2] if isinstance(longrepr, tuple) and len(longrepr) == 3 else str(longrepr)
        reasons[reason.removeprefix("Skipped: ")] += 1
    tr = terminalreporter
    tr.section("what this run did not test", sep="-")
    tr.write_line(f"{len(skipped)} test(s) skipped:")
    for reason, n in reasons.most_common():  # each reason says what would run them
        tr.write_line(f"  {n:3d} x {reason}")
    if warned:
        tr.write_line("  the scale-out test ran through the fake cluster-generic scheduler, not SLURM (set "
                      "SELFSENSE_TEST_SLURM=1 to start a local SLURM cluster as root)")
