"""Record helpers shared by the benchmark scripts (run as ``python benchmarks/<script>.py``, so this directory is on
``sys.path``)."""
from __future__ import annotations

from typing import Iterable, Sequence

import pandas as pd

DEVICE_KEYS = ("family", "preset", "seed")
"""What names one device of the cross-device benchmark (``selfsense devices bench``) in its records."""


def one_per_device(frames: Iterable[pd.DataFrame], keys: Sequence[str] = DEVICE_KEYS) -> pd.DataFrame:
    """The records of one run kept in several parts (``frames``, in the order the parts were made: a device scored
    again after a fix is in a later part): one row per device, taken from a part where it was scored (``status`` ok;
    a part without a ``status`` column counts as scored), from the latest such part where several scored it, else
    from the latest part. The rows come out ordered by that rule, not by device."""
    parts = []
    for k, r in enumerate(frames):
        ok = (r["status"] == "ok") if "status" in r else pd.Series(True, index=r.index)
        parts.append(r.assign(_ok=ok.to_numpy(dtype=bool), _order=k))
    if not parts:
        raise ValueError("one_per_device: no records given")
    r = pd.concat(parts, ignore_index=True).sort_values(["_ok", "_order"], kind="stable")
    return r.drop_duplicates(list(keys), keep="last").drop(columns=["_ok", "_order"])
