"""``selfsense estimate``: chunked streaming estimation of a long raw DAQ log (Parquet).

    selfsense estimate --model results/<d>/model/sensing.json --dataset data/raw/<d> \\
        --log FILE.parquet --out OUT.parquet [--chunk 1000000] [--full] [--offset relay|VOLTS]

Reads the log in record batches (``pyarrow.parquet.ParquetFile.iter_batches``), feeds them through
:class:`selfsense.sensing.streaming.SelfSensingStream` (all state carried between chunks, so the result equals
the batch pipeline ``stages.ingest`` -> ``SelfSensingEstimator.estimate`` on the whole log) and writes each chunk
as a row group of the output (``pyarrow.parquet.ParquetWriter`` into a temp file, ``os.replace`` at the end: a
failure leaves no partial output). Memory is bounded by the chunk size, not the log length.

Output columns: ``t`` [s], ``dx_hat`` [m], ``f_hat`` [N]; with ``--full`` also ``q`` [C], ``V`` [V], ``V_H`` [V],
``V_p`` [V], ``dx_raw`` [m], ``f_raw`` [N]. Log columns used: ``t, u_cmd, v_shunt`` and ``relay`` (optional with
``--offset VOLTS``), renamed/scaled by the dataset's ``rig.yaml: channel_map`` if it has one.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

__all__ = ["main", "estimate_log"]

_AUX = ("q", "V", "V_H", "V_p", "dx_raw", "f_raw")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="selfsense estimate", description=__doc__.split("\n\n")[0], allow_abbrev=False)
    p.add_argument("--model", required=True, help="fitted estimator JSON (results/<d>/model/sensing.json)")
    p.add_argument("--dataset", required=True, help="dataset directory holding rig.yaml (data/raw/<d>)")
    p.add_argument("--log", required=True, help="raw DAQ log (.parquet) with t, u_cmd, v_shunt[, relay]")
    p.add_argument("--out", required=True, help="output .parquet")
    p.add_argument("--chunk", type=int, default=1_000_000, help="samples per chunk (default 1000000)")
    p.add_argument("--full", action="store_true", help="also write q, V, V_H, V_p, dx_raw, f_raw")
    p.add_argument("--offset", default="relay",
                   help="in-amp offset of V_s: 'relay' (mean over the first shorted segment, default) or volts")
    return p


def estimate_log(model: str | Path, dataset: str | Path, log: str | Path, out: str | Path,
                 chunk: int = 1_000_000, full: bool = False, offset: str | float = "relay",
                 progress: bool | None = None) -> int:
    """Stream ``log`` through the fitted model into ``out`` chunk by chunk; returns the number of samples."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from tqdm import tqdm

    from selfsense import io as sio
    from selfsense.sensing.streaming import SelfSensingStream

    if chunk < 1:
        raise ValueError(f"--chunk must be >= 1, got {chunk}")
    rig = sio.load_rig(dataset)
    stream = SelfSensingStream.from_json(model, rig, offset=offset)
    cmap = getattr(rig, "channel_map", None)
    fcol = {c: (cmap.file_column(c) if cmap else c) for c in ("t", "u_cmd", "v_shunt", "relay")}
    scale = {c: float(cmap.scale[c]) for c in fcol if cmap and c in cmap.scale}

    pf = pq.ParquetFile(str(log))
    names = set(pf.schema_arrow.names)
    need = [fcol[c] for c in ("t", "u_cmd", "v_shunt")]
    missing = [c for c in need if c not in names]
    if missing:
        raise ValueError(f"{log}: missing column(s) {missing}; expected t, u_cmd, v_shunt and relay")
    has_relay = fcol["relay"] in names
    if not has_relay and offset == "relay":
        raise ValueError(f"{log}: no relay column, so the in-amp offset cannot be estimated; pass --offset VOLTS")
    cols = need + ([fcol["relay"]] if has_relay else [])

    out_cols = ["t", "dx_hat", "f_hat"] + (list(_AUX) if full else [])
    schema = pa.schema([(c, pa.float64()) for c in out_cols])
    n_total = pf.metadata.num_rows
    done = 0

    def col(batch, name):
        a = batch.column(fcol[name]).to_numpy(zero_copy_only=False).astype(np.float64, copy=False)
        return scale[name] * a if name in scale else a

    with sio.atomic_write(out, "wb") as fh:
        writer = pq.ParquetWriter(fh, schema, compression="zstd")
        try:
            with tqdm(total=n_total, unit="sample", unit_scale=True, disable=None if progress is None else not progress,
                      desc="estimate", file=sys.stderr) as bar:
                for batch in pf.iter_batches(batch_size=chunk, columns=cols):
                    t = col(batch, "t")
                    relay = col(batch, "relay") if has_relay else None
                    res = stream.process(col(batch, "u_cmd"), col(batch, "v_shunt"), relay, t=t, full=full)
                    if full:
                        arrays = [t, res["dx_hat"], res["f_hat"]] + [res[c] for c in _AUX]
                    else:
                        arrays = [t, res[0], res[1]]
                    writer.write_table(pa.Table.from_arrays([pa.array(a) for a in arrays], schema=schema))
                    done += len(t)
                    bar.update(len(t))
        finally:
            writer.close()
    return done


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    offset: str | float = args.offset
    if offset != "relay":
        try:
            offset = float(offset)
        except ValueError:
            print(f"selfsense estimate: error: --offset must be 'relay' or a number of volts, got {offset!r}",
                  file=sys.stderr)
            return 2
    # StreamError, ContractError, missing files, bad columns: one line per problem and exit 2 (selfsense.cli)
    n = estimate_log(args.model, args.dataset, args.log, args.out, chunk=args.chunk, full=args.full, offset=offset)
    print(f"selfsense estimate: {n} samples -> {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
