"""Sample budgets: memory bounded by a budget, not by the length of a trial.

Stages that need a whole trial in memory at once, several times over (the gap diagnostic refits the estimator
many times; a figure draws every point), work on at most a budget of samples per trial. Above it they
*decimate* and say so (the gap verdict's ``decimated`` entry, the figure captions):

* :func:`read_parquet_decimated` -- every k-th row of a Parquet file, read batch by batch (peak memory: one
  batch plus the kept rows), for figures;
* :func:`block_mean` -- the mean over blocks of k samples (an anti-alias filter before keeping one sample in k;
  the relay column keeps the block's maximum, so a block touching a shorted sample stays shorted), for the gap
  diagnostic, whose models are fitted on the drive's time scale (0.1-10 Hz in the thesis, seconds of creep).
"""
from __future__ import annotations

import math
import os
from typing import Iterable

import numpy as np
import pandas as pd

__all__ = ["FIGURE_MAX_ROWS", "GAP_MAX_SAMPLES", "decimation_factor", "read_parquet_decimated", "block_mean"]

#: rows per trial drawn in a figure (a 10-inch panel shows < 2,000 pixels across)
FIGURE_MAX_ROWS = 100_000
#: samples per trial for the gap diagnostic (tweezer_sim trials: 14,000-20,000 samples; 10 min at 10 kHz: 6e6)
GAP_MAX_SAMPLES = int(os.environ.get("SELFSENSE_GAP_MAX_SAMPLES", 50_000))


def decimation_factor(n: int, budget: int) -> int:
    """Smallest integer k with ceil(n / k) <= budget (1 when n fits)."""
    if budget < 1:
        raise ValueError(f"sample budget: expected >= 1, found {budget}")
    return max(1, math.ceil(n / budget))


def read_parquet_decimated(path, max_rows: int = FIGURE_MAX_ROWS, columns: Iterable[str] | None = None,
                           batch_size: int = 262_144) -> tuple[pd.DataFrame, int]:
    """``(frame of every k-th row, k)`` of a Parquet file with ``k = decimation_factor(rows, max_rows)``.

    Read in record batches, so the peak memory is one batch plus the kept rows whatever the file's length.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    pf = pq.ParquetFile(str(path))
    n = pf.metadata.num_rows
    k = decimation_factor(n, max_rows)
    cols = list(columns) if columns is not None else None
    if k == 1:
        return pf.read(columns=cols).to_pandas(), 1
    parts = []
    offset = 0  # global index of the first row of the current batch
    for batch in pf.iter_batches(batch_size=batch_size, columns=cols):
        first = (-offset) % k
        idx = np.arange(first, batch.num_rows, k)
        if idx.size:
            parts.append(batch.take(pa.array(idx)))
        offset += batch.num_rows
    table = pa.Table.from_batches(parts, schema=parts[0].schema) if parts else pf.schema_arrow.empty_table()
    return table.to_pandas(), k


def block_mean(df: pd.DataFrame, k: int, max_columns: Iterable[str] = ("relay",)) -> pd.DataFrame:
    """Mean over consecutive blocks of ``k`` rows (the last, shorter block included); ``max_columns`` take the
    block maximum instead. ``k = 1`` returns ``df`` unchanged. NaN blocks stay NaN (mean of all-NaN)."""
    if k <= 1:
        return df
    n = len(df)
    m = math.ceil(n / k)
    pad = m * k - n
    out = {}
    maxc = set(max_columns)
    for c in df.columns:
        x = df[c].to_numpy(dtype=np.float64)
        if pad:
            x = np.concatenate([x, np.full(pad, np.nan)])
        blocks = x.reshape(m, k)
        with np.errstate(all="ignore"):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                out[c] = np.nanmax(blocks, axis=1) if c in maxc else np.nanmean(blocks, axis=1)
    res = pd.DataFrame(out)
    res.attrs.update(df.attrs)
    res.attrs["decimation"] = k
    return res
