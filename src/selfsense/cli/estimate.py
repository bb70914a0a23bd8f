"""``selfsense estimate``: chunked streaming estimation of a long raw DAQ log (Parquet, CSV, TDMS or MAT).

    selfsense estimate --model results/<d>/model/sensing.json --dataset data/raw/<d> \\
        --log FILE.parquet --out OUT.parquet [--chunk 1000000] [--full] [--offset relay|VOLTS]

Reads the log in chunks (Parquet record batches, CSV chunks; TDMS and MAT are read whole, then chunked), feeds them through
:class:`selfsense.sensing.streaming.SelfSensingStream` (all state carried between chunks, so the result equals
the batch pipeline ``stages.ingest`` -> ``SelfSensingEstimator.estimate`` on the whole log) and writes each chunk
as a row group of the output (``pyarrow.parquet.ParquetWriter`` into a temp file, ``os.replace`` at the end: a
failure leaves no partial output). Memory is bounded by the chunk size, not the log length.

A model with the offset-drift member (a charge drift fitted over the rest segments of the whole trial) is estimated
in batch, exactly as the pipeline does, with the whole log in memory, unless ``--drift causal`` streams it with the
drift fitted on the rest segments seen so far (``SelfSensingStream(drift="causal")``).

Output columns: ``t`` [s], ``dx_hat`` [m], ``f_hat`` [N]; with ``--full`` also ``q`` [C], ``V`` [V], ``V_H`` [V],
``V_p`` [V], ``dx_raw`` [m], ``f_raw`` [N]. Log columns used: ``t, u_cmd, v_shunt`` and ``relay`` (optional with
``--offset VOLTS``), renamed/scaled by the dataset's ``rig.yaml: channel_map`` if it has one.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

__all__ = ["main", "estimate_log"]

_AUX = ("q", "V", "V_H", "V_p", "dx_raw", "f_raw")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="selfsense estimate", description=__doc__.split("\n\n")[0], allow_abbrev=False)
    p.add_argument("--model", required=True, help="fitted estimator JSON (results/<d>/model/sensing.json)")
    p.add_argument("--dataset", required=True, help="dataset directory holding rig.yaml (data/raw/<d>)")
    p.add_argument("--log", required=True, help="raw DAQ log (.parquet, .csv, .tdms or .mat) with t, u_cmd, v_shunt[, relay]")
    p.add_argument("--out", required=True, help="output .parquet")
    p.add_argument("--chunk", type=int, default=1_000_000, help="samples per chunk (default 1000000)")
    p.add_argument("--full", action="store_true", help="also write q, V, V_H, V_p, dx_raw, f_raw")
    p.add_argument("--drift", choices=("batch", "causal"), default="batch",
                   help="a model with the offset-drift member: estimate it in batch, exactly the pipeline (default; "
                        "the whole log in memory), or stream it with the drift fitted on the rest segments seen so "
                        "far (causal; memory bounded)")
    p.add_argument("--trial", default=None,
                   help="the log's trial name in the trials.csv the model was fitted with: a model with the "
                        "temperature member divides the charge by that trial's campaign scale (default: the "
                        "calibration's scale, 1)")
    p.add_argument("--offset", default="relay",
                   help="in-amp offset of V_s: 'relay' (mean over the first shorted segment, default) or volts")
    return p


_NEED = ("t", "u_cmd", "v_shunt")


def _log_chunks(log: str | Path, rig, chunk: int):
    """``(n_samples or None, has_relay, iterator of {channel: float64 array}})`` for a raw log in any format the
    pipeline reads (selfsense.io): Parquet (record batches) and CSV (pandas chunks; a scope preamble and units row
    are skipped, extra columns ignored) are read chunk by chunk, memory bounded by ``chunk``; TDMS and MAT are
    read whole by :func:`selfsense.io.formats.read_tdms` / ``read_mat`` and then fed in chunks. ``rig.yaml:
    channel_map`` names and scales apply."""
    import pandas as pd

    from selfsense.io import logs as slogs
    from selfsense.io.errors import ContractError, Problem

    log = Path(log)
    if not log.is_file():
        raise FileNotFoundError(2, "No such file or directory", str(log))
    cmap = getattr(rig, "channel_map", None)
    fcol = {c: (cmap.file_column(c) if cmap else c) for c in (*_NEED, "relay")}
    scale = {c: float(cmap.scale[c]) for c in fcol if cmap and c in cmap.scale}
    kind = slogs._kind(log, rig)

    def scaled(block: dict) -> dict:
        return {c: (scale[c] * a if c in scale else a) for c, a in block.items()}

    def missing_error(names) -> ValueError:
        miss = [fcol[c] for c in _NEED if fcol[c] not in names]
        return ValueError(f"{log}: missing column(s) {miss}; expected t, u_cmd, v_shunt and relay")

    if kind == "parquet":
        import pyarrow.parquet as pq

        pf = pq.ParquetFile(str(log))
        names = set(pf.schema_arrow.names)
        if any(fcol[c] not in names for c in _NEED):
            raise missing_error(names)
        use = [c for c in fcol if fcol[c] in names]

        def it():
            for b in pf.iter_batches(batch_size=chunk, columns=[fcol[c] for c in use]):
                yield scaled({c: b.column(fcol[c]).to_numpy(zero_copy_only=False).astype(np.float64, copy=False)
                              for c in use})
        return pf.metadata.num_rows, "relay" in use, _checked(log, fcol, it())
    if kind == "csv":
        header, probs, skip, units = slogs._csv_header(log.name, log, log.stat().st_size,
                                                       tuple(fcol[c] for c in _NEED))
        if probs:
            raise ValueError(str(probs[0]))
        if any(fcol[c] not in header for c in _NEED):
            raise missing_error(header)
        use = [c for c in fcol if fcol[c] in header]
        try:
            reader = pd.read_csv(log, usecols=[fcol[c] for c in use], chunksize=chunk,
                                 skiprows=list(range(skip)) + ([skip + 1] if units else []) or None,
                                 encoding="utf-8-sig", skipinitialspace=True)
        except UnicodeDecodeError as e:   # pandas decodes its first buffer when the reader is made
            raise ContractError(Problem(log.name, None, None, "UTF-8 text",
                                        f"an undecodable byte {e.object[e.start:e.start + 1]!r} in the first "
                                        "rows"), str(log)) from None

        def it():
            start = 0
            with reader:
                while True:
                    try:
                        df = next(reader)
                    except StopIteration:
                        return
                    except UnicodeDecodeError as e:
                        raise ContractError(Problem(log.name, None, None, "UTF-8 text",
                                                    f"an undecodable byte {e.object[e.start:e.start + 1]!r} in data "
                                                    f"row {start + 1} or later"), str(log)) from None
                    # the contract's cell check: a text cell names its column and (file-wide) row
                    num, probs = slogs._bad_cells(log.name, df, [fcol[c] for c in use])
                    if probs:
                        raise ContractError([replace(p, row=p.row + start) for p in probs], str(log))
                    start += len(df)
                    yield scaled({c: num[fcol[c]].to_numpy(np.float64) for c in use})
        with open(log, "rb") as fh:  # row count estimate for the progress bar (bytes per line of the first 64 KiB)
            head = fh.read(1 << 16)
        n_est = int(log.stat().st_size / max(len(head) / max(head.count(b"\n"), 1), 1.0))
        return n_est, "relay" in use, _checked(log, fcol, it())
    if kind in ("tdms", "mat"):
        from selfsense.io.formats import read_mat, read_tdms

        cols = dict(cmap.columns) if cmap else None
        grp = cmap.group if cmap else None
        if kind == "tdms":
            df = read_tdms(log, cols, group=grp, need=())   # the references are not read here
        else:
            dt = None if cols and "t" in cols else rig.dt
            df = read_mat(log, cols, group=grp, dt=dt, need=())
        arrays = scaled({c: df[c].to_numpy(np.float64) for c in (*_NEED, "relay")})

        def it():
            for i in range(0, len(df), chunk):
                yield {c: a[i:i + chunk] for c, a in arrays.items()}
        return len(df), True, _checked(log, fcol, it())
    raise ValueError(f"{log}: expected a .parquet, .csv, .tdms or .mat log (or rig.yaml format), found "
                     f"{log.suffix or 'no suffix'!r}")


def _checked(log: Path, fcol: dict, blocks):
    """The blocks of a log, each checked before the stream reads it, as the dataset contract checks a whole log
    (:func:`selfsense.io.logs.check_signals`, with its rules for the relay and the time order): every sample of
    ``t``, ``u_cmd``, ``v_shunt`` and ``relay`` finite, ``relay`` 0 or 1 and ``t`` strictly increasing, across block
    boundaries too. A violation raises :class:`ContractError` naming the file, its column and the 1-based data row
    (not a chunk's), before anything of that block is estimated: a NaN would otherwise run through the charge
    integral and every later sample."""
    from selfsense.io.errors import ContractError, Problem
    from selfsense.io.logs import (
        first_true,
        relay_not_binary,
        time_steps_not_increasing,
    )

    start, prev = 0, None
    for block in blocks:
        probs = []
        for c in ("t", "u_cmd", "v_shunt", "relay"):
            x = block.get(c)
            bad = None if x is None else first_true(~np.isfinite(x))
            if bad is not None:
                i, count = bad
                probs.append(Problem(log.name, fcol[c], start + i + 1,
                                     f"finite values in every sample ({count} non-finite in rows "
                                     f"{start + 1}-{start + len(x)})", "NaN" if np.isnan(x[i]) else float(x[i])))
        r = block.get("relay")
        bad = None if r is None or probs else relay_not_binary(r)
        if bad is not None:
            i = bad[0]
            probs.append(Problem(log.name, fcol["relay"], start + i + 1,
                                 "0 or 1 (the relay channel cannot be scaled: log it as 0 / 1, e.g. threshold a "
                                 "0 / 5 V signal)", float(r[i])))
        t = block["t"]
        if len(t) and not probs:
            tt = t if prev is None else np.concatenate([[prev], t])
            first = 1 if prev is None else 0   # tt[k + 1] is data row start + k + first + 1 (1-based)
            for what, k, count in sorted(time_steps_not_increasing(tt), key=lambda f: f[1])[:1]:   # the earliest
                probs.append(Problem(log.name, fcol["t"], start + k + first + 1, "strictly increasing time",
                                     f"{what} time t = {tt[k + 1]:.9g} s after {tt[k]:.9g} s"))
        if probs:
            raise ContractError(probs, str(log))
        if len(t):
            prev = float(t[-1])
        start += len(t)
        yield block


def estimate_log(model: str | Path, dataset: str | Path, log: str | Path, out: str | Path,
                 chunk: int = 1_000_000, full: bool = False, offset: str | float = "relay",
                 progress: bool | None = None, drift: str = "batch", trial: str | None = None) -> int:
    """Stream ``log`` through the fitted model into ``out`` chunk by chunk; returns the number of samples. ``trial``:
    the log's name in the fitted trials.csv (the temperature member's campaign scale; None: 1)."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from tqdm import tqdm

    from selfsense import io as sio
    from selfsense.sensing.streaming import SelfSensingStream

    if chunk < 1:
        raise ValueError(f"--chunk must be >= 1, got {chunk}")
    # --out must not resolve to (or lie in) an input or a raw dataset, whatever the folder names
    sio.check_output_file(out, [model, dataset, log])
    rig = sio.load_rig(dataset)
    if drift not in ("batch", "causal"):
        raise ValueError(f"--drift must be 'batch' or 'causal', got {drift!r}")
    if not streamable(model) and drift == "batch":
        return _estimate_batch(model, rig, log, out, chunk, full, offset, trial)
    n_total, has_relay, chunks = _log_chunks(log, rig, chunk)
    if not has_relay and offset == "relay":
        raise ValueError(f"{log}: no relay column, so the in-amp offset cannot be estimated; pass --offset VOLTS")
    first = next(chunks, None)
    # H's creep terms at the log's sample period (median step of the first chunk), as the batch uses the trial's
    dt = None
    if first is not None and len(first["t"]) > 1:
        dt = float(np.median(np.diff(first["t"])))
        dt = dt if dt > 0 else None
    stream = SelfSensingStream.from_json(model, rig, offset=offset, dt=dt,
                                         drift="causal" if drift == "causal" else "refuse", trial=trial)
    chunks = _chain(first, chunks)

    out_cols = ["t", "dx_hat", "f_hat"] + (list(_AUX) if full else [])
    schema = pa.schema([(c, pa.float64()) for c in out_cols])
    done = 0

    with sio.atomic_write(out, "wb") as fh:
        writer = pq.ParquetWriter(fh, schema, compression="zstd")
        try:
            with tqdm(total=n_total, unit="sample", unit_scale=True, disable=None if progress is None else not progress,
                      desc="estimate", file=sys.stderr) as bar:
                for block in chunks:
                    t = block["t"]
                    res = stream.process(block["u_cmd"], block["v_shunt"], block.get("relay"), t=t, full=full)
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


def _chain(first, rest):
    if first is not None:
        yield first
    yield from rest


def streamable(model: str | Path) -> bool:
    """True for models the stream runs: every H model and member except the offset-drift member (a charge drift
    fitted over the rest segments of the whole trial, which needs the whole trial)."""
    import json

    d = json.loads(Path(model).read_text())
    return not d.get("offset_drift")


def _estimate_batch(model, rig, log, out, chunk: int, full: bool, offset, trial: str | None = None) -> int:
    """Whole-log estimation for models the stream does not run (the offset-drift member: the rest-segment drift
    estimate needs the whole trial): the log is read in chunks, concatenated,
    converted as the pipeline does (selfsense.io.to_si, selfsense.signals.prepare_trial) and estimated with
    ``SelfSensingEstimator.estimate``, exactly the batch pipeline. Memory grows with the log length."""
    import json

    import numpy as np
    import pandas as pd

    from selfsense import io as sio
    from selfsense.sensing.estimator import SelfSensingEstimator
    from selfsense.signals import prepare_trial

    est = SelfSensingEstimator.from_dict(json.loads(Path(model).read_text()), rig)
    n_total, has_relay, chunks = _log_chunks(log, rig, chunk)
    if not has_relay and offset == "relay":
        raise ValueError(f"{log}: no relay column, so the in-amp offset cannot be estimated; pass --offset VOLTS")
    blocks = list(chunks)
    cols = {c: np.concatenate([b[c] for b in blocks]) for c in blocks[0]} if blocks else {}
    if not cols or len(cols["t"]) < 2:
        raise ValueError(f"{log}: fewer than 2 samples")
    raw = pd.DataFrame(cols)
    if "relay" not in raw:
        raw["relay"] = 0.0
    raw["laser"] = np.nan
    raw["load_cell"] = np.nan
    sig = prepare_trial(sio.to_si(raw, rig, None), rig, offset=offset)
    if trial is None and (est.temperature_ or {}).get("applied"):
        print(f"selfsense estimate: {model} carries the temperature member and no --trial was given: the charge is "
              "taken at the calibration's scale", file=sys.stderr)
    res = est.estimate(sig, trial=trial)
    names = ["t", "dx_hat", "f_hat"] + (list(_AUX) if full else [])
    frame = pd.DataFrame({c: res[c].to_numpy() if c in res else sig[c].to_numpy() for c in names})
    sio.write_parquet_atomic(frame, out)
    print(f"selfsense estimate: {est.hysteresis_.label() if hasattr(est.hysteresis_, 'label') else 'model'} runs in "
          f"batch (whole log in memory), not sample by sample", file=sys.stderr)
    return len(frame)


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
    n = estimate_log(args.model, args.dataset, args.log, args.out, chunk=args.chunk, full=args.full, offset=offset,
                     drift=args.drift, trial=args.trial)
    print(f"selfsense estimate: {n} samples -> {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
