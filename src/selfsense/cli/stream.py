"""``selfsense stream``: estimates as the samples come, for any DAQ program that can write CSV lines.

    daq_program | selfsense stream --model results/<d>/model/sensing.json --dataset data/raw/<d> > estimates.csv
    selfsense stream --model ... --dataset ... --input log.csv --follow      # a file that is still being written

Input: CSV text with a header line naming the channels (``t, u_cmd, v_shunt, relay``; the dataset's
``rig.yaml: channel_map`` renames and scales them as for the pipeline), then one sample per line. Every line is
estimated as it arrives (:meth:`selfsense.sensing.streaming.SelfSensingStream.step`, all state carried, O(1) memory)
and ``t,dx_hat,f_hat`` (s, m, N) is written and flushed at once, so the output equals the batch pipeline on the same
samples. With ``--follow`` the input file is read on as it grows, until the command is interrupted (Ctrl-C).

Every model the pipeline fits streams (any H(q) model kind, the leakage and rest-offset members, sliding offset and
limiting). A model with the offset-drift member (fitted over whole trials in batch) stops at once with an error
naming it and the member, unless ``--drift causal`` asks for the drift fitted on the rest segments seen so far
(:class:`selfsense.sensing.streaming.CausalOffsetDrift`). A model with the temperature member divides the charge by
the campaign scale of the trial named with ``--trial``. H's creep terms are discretised at ``--dt`` (default: the calibration's
sample time). A malformed line (a
field that is not a number, a wrong field count, a relay other than 0/1, a time that does not increase) stops with
its line number; what was written before it stays valid.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

__all__ = ["main"]

REQUIRED = ("t", "u_cmd", "v_shunt")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="selfsense stream", allow_abbrev=False, description=__doc__.split("\n\n")[0])
    p.add_argument("--model", required=True, help="fitted estimator JSON (results/<d>/model/sensing.json)")
    p.add_argument("--dataset", required=True, help="dataset directory holding rig.yaml (data/raw/<d>)")
    p.add_argument("--input", default="-", help="CSV input file, or - for standard input (default)")
    p.add_argument("--follow", action="store_true", help="keep reading --input as it grows (until Ctrl-C)")
    p.add_argument("--poll", type=float, default=0.05, help="seconds between reads of a growing file (default 0.05)")
    p.add_argument("--drift", choices=("refuse", "causal"), default="refuse",
                   help="a model with the offset-drift member: refuse it (default) or fit the drift on the rest "
                        "segments seen so far (causal)")
    p.add_argument("--dt", type=float, default=None,
                   help="sample period [s] for H's creep terms (default: the calibration's sample time)")
    p.add_argument("--offset", default="relay",
                   help="in-amp offset of V_s: 'relay' (mean over the first shorted segment, default) or volts")
    p.add_argument("--trial", default=None,
                   help="the log's trial name in the trials.csv the model was fitted with: a model with the "
                        "temperature member divides the charge by that trial's campaign scale, as "
                        "selfsense estimate --trial does (default: the calibration's scale, 1, with a warning)")
    return p


def _lines(fh, follow: bool, poll: float):
    """Complete lines of ``fh``; with ``follow``, waits for more at the end of the file instead of stopping."""
    buf = ""
    while True:
        chunk = fh.readline()
        if chunk:
            buf += chunk
            if buf.endswith("\n"):
                yield buf
                buf = ""
            continue
        if not follow:
            if buf:
                yield buf
            return
        time.sleep(poll)


def _columns(header: str, rig, source: str) -> tuple[list[int], dict[str, float]]:
    """Indices of t, u_cmd, v_shunt[, relay] in the header and their scales (rig.yaml channel_map)."""
    names = [h.strip() for h in header.strip().split(",")]
    cmap = getattr(rig, "channel_map", None) or {}
    cols = dict(getattr(cmap, "columns", None) or (cmap.get("columns", {}) if isinstance(cmap, dict) else {}) or {})
    scales = dict(getattr(cmap, "scale", None) or (cmap.get("scale", {}) if isinstance(cmap, dict) else {}) or {})
    idx = []
    for c in (*REQUIRED, "relay"):
        name = cols.get(c, c)
        if name in names:
            idx.append(names.index(name))
        elif c != "relay":
            raise ValueError(f"{source}: header line 1: channel {name!r} ({c}) not found; the header has {names}")
        else:
            idx.append(-1)
    return idx, {c: float(scales.get(c, 1.0)) for c in (*REQUIRED, "relay")}


def stream_lines(model, dataset, lines, out, offset="relay", source: str = "<stdin>", dt: float | None = None,
                 drift: str = "refuse", trial: str | None = None) -> int:
    """Estimate every CSV line of ``lines`` (the first is the header) and write ``t,dx_hat,f_hat`` to ``out`` as each
    arrives; returns the number of samples. ``dataset``: the directory holding rig.yaml, or the rig itself;
    ``trial``: the log's name in the fitted trials.csv (:class:`~selfsense.sensing.streaming.SelfSensingStream`)."""
    from selfsense import io as sio
    from selfsense.cli.estimate import streamable
    from selfsense.sensing.streaming import SelfSensingStream

    if not streamable(model) and drift != "causal":
        raise ValueError(f"{model}: the model carries the offset-drift member (offset_drift: true), a drift fitted "
                         "over the rest segments of whole trials, which a stream has not seen yet; pass --drift causal "
                         "(the drift fitted on the rest segments seen so far), refit with calibration: drift: off, or "
                         "use selfsense estimate (batch) on the finished log")
    rig = sio.load_rig(dataset) if isinstance(dataset, (str, Path)) else dataset
    off = offset if offset == "relay" else float(offset)
    stream = SelfSensingStream.from_json(model, rig, offset=off, dt=dt, drift=drift, trial=trial)
    it = iter(lines)
    header = next(it, None)
    if header is None:
        raise ValueError(f"{source}: empty input (expected a header line naming t, u_cmd, v_shunt[, relay])")
    idx, sc = _columns(header, rig, source)
    if idx[3] < 0 and off == "relay":
        raise ValueError(f"{source}: no relay column, so the in-amp offset cannot be estimated; pass --offset VOLTS")
    out.write("t,dx_hat,f_hat\n")
    out.flush()
    n = 0
    for lineno, line in enumerate(it, start=2):
        if not line.strip():
            continue
        f = line.strip().split(",")
        try:
            t, u, v = (float(f[i]) * sc[c] for i, c in zip(idx[:3], REQUIRED))
            r = float(f[idx[3]]) if idx[3] >= 0 else 0.0
        except (ValueError, IndexError):
            raise ValueError(f"{source}: line {lineno}: expected numbers in the columns t, u_cmd, v_shunt"
                             f"{', relay' if idx[3] >= 0 else ''}, found {line.strip()[:120]!r}") from None
        if not all(math.isfinite(x) for x in (t, u, v, r)):   # 'nan' / 'inf' parse as numbers: one would poison
            raise ValueError(f"{source}: line {lineno}: expected finite numbers in the columns t, u_cmd, v_shunt"
                             f"{', relay' if idx[3] >= 0 else ''} (a NaN would corrupt the charge integral of every "
                             f"later sample), found {line.strip()[:120]!r}")
        try:
            dx, fo = stream.step(u, v, r, t)
        except ValueError as exc:
            raise ValueError(f"{source}: line {lineno}: {exc}") from None
        out.write(f"{t!r},{dx!r},{fo!r}\n")
        out.flush()
        n += 1
    return n


def main(argv: list[str] | None = None) -> int:
    a = _parser().parse_args(argv)
    if a.follow and a.input == "-":
        raise ValueError("--follow reads a file that is still being written: give it with --input FILE")
    if a.input == "-":
        return 0 if stream_lines(a.model, a.dataset, _lines(sys.stdin, False, a.poll), sys.stdout, a.offset,
                                 dt=a.dt, drift=a.drift, trial=a.trial) >= 0 else 1
    path = Path(a.input)
    if not path.is_file():
        raise FileNotFoundError(2, "No such file or directory", str(path))
    with open(path, newline="") as fh:
        try:
            stream_lines(a.model, a.dataset, _lines(fh, a.follow, a.poll), sys.stdout, a.offset, source=str(path),
                         dt=a.dt, drift=a.drift, trial=a.trial)
        except KeyboardInterrupt:  # --follow ends with Ctrl-C: what was written is complete
            return 0
    return 0
