"""Command-line helpers shared by the benchmark scripts (run as ``python benchmarks/<script>.py``, so this
directory is on ``sys.path``)."""
from __future__ import annotations

import argparse


def int_ranges(spec: str) -> list[int]:
    """Integers of a comma-separated list of numbers and inclusive ranges: ``"0-4,7,10-11"`` ->
    ``[0, 1, 2, 3, 4, 7, 10, 11]``, in the order given. Usable as an argparse ``type``: a malformed part raises
    :class:`argparse.ArgumentTypeError` naming it and the expected form."""
    out: list[int] = []
    for part in str(spec).split(","):
        a, dash, b = part.strip().partition("-")
        try:
            lo = int(a)
            hi = int(b) if dash else lo
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{part.strip()!r} in {spec!r}: expected an integer or an inclusive range such as 0-9") from None
        if hi < lo:
            raise argparse.ArgumentTypeError(f"{part.strip()!r} in {spec!r}: the range ends before it starts")
        out.extend(range(lo, hi + 1))
    return out

