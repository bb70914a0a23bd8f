"""The ``selfsense`` command.

Each subcommand is one module of this package (``selfsense.cli.<command>``), imported lazily, so that
``selfsense validate`` does not pay for numba or cvxpy start-up; the science each one calls lives in the
subpackages below (io, sim, sensing, gap, hysteresis, report). ``selfsense <command> --help`` describes every
option of a command.

Errors a user can cause (a bad dataset, a missing file, an invalid value) end with one line on stderr,
``selfsense <command>: error: <what, where, what was expected>``, and exit code 2, never a traceback; set
``SELFSENSE_TRACEBACK=1`` to see the traceback as well.
"""
from __future__ import annotations

import importlib
import os
import sys

from selfsense import version  # noqa: F401  (re-exported: selfsense.cli.version)

#: subcommand -> (module, function, one-line description); each function takes ``argv: list[str]`` and returns an
#: exit code.
SUBCOMMANDS: dict[str, tuple[str, str, str]] = {
    "init": ("selfsense.cli.init", "main", "write a template dataset folder (rig.yaml, trials.csv) for your own rig"),
    "validate": ("selfsense.cli.validate", "main", "check a raw dataset folder against the data contract"),
    "simulate": ("selfsense.cli.simulate", "main", "write a virtual-tweezer dataset and its truth folder"),
    "run": ("selfsense.cli.run", "main",
            "run the Snakemake pipeline in the current directory (options go to Snakemake)"),
    "estimate": ("selfsense.cli.estimate", "main",
                 "estimate a DAQ log with a fitted model (CSV, Parquet, TDMS, MAT; streamed where the model allows)"),
    "stream": ("selfsense.cli.stream", "main",
               "estimate samples as they come: CSV lines on stdin (or a growing file) -> t,dx_hat,f_hat lines"),
    "export-c": ("selfsense.cli.export_c", "main",
                 "write a fitted model as dependency-free C99 (ss_init, ss_step) for a real-time controller"),
    "export": ("selfsense.cli.export", "main",
               "write each trial's results as .mat and .csv with units, V, q, estimates, coefficients, config"),
    "gap": ("selfsense.cli.gap", "main", "sim-to-real gap diagnostic (diagnose, blind, blind-calibrate)"),
    "ri": ("selfsense.cli.ri", "main", "RI hysteresis model checks against published data"),
    "fit-external": ("selfsense.cli.fit_external", "main",
                     "fit the hysteresis models to the external measured data sets"),
    "devices": ("selfsense.cli.devices", "main",
                "cross-device accuracy benchmark: Table 3 on virtual devices of several hysteresis families"),
}


def _usage() -> str:
    lines = ["usage: selfsense [--version] [--help] <command> [options]", "",
             "Force and displacement self-sensing for amplified piezoelectric actuators.", "", "commands:"]
    for name, (_, _, desc) in SUBCOMMANDS.items():
        lines.append(f"  {name:<13} {desc}")
    lines += ["", "'selfsense <command> --help' describes the options of a command."]
    return "\n".join(lines)


def _user_errors() -> tuple[type[BaseException], ...]:
    errs: list[type[BaseException]] = [ValueError, OSError, KeyError]
    try:
        from selfsense.io.errors import ContractError

        errs.insert(0, ContractError)
    except Exception:  # pragma: no cover
        pass
    return tuple(errs)


def _one_line(exc: BaseException) -> str:
    msg = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
    if isinstance(exc, OSError) and getattr(exc, "filename", None) and exc.strerror:
        msg = f"{exc.filename}: {exc.strerror}"
    return " ".join((msg or type(exc).__name__).split())


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in {"-h", "--help"}:
        print(_usage(), file=sys.stdout if argv else sys.stderr)
        return 0 if argv else 2
    if argv[0] in {"-V", "--version"}:
        print(f"selfsense {version()}")
        return 0
    cmd, rest = argv[0], argv[1:]
    if cmd not in SUBCOMMANDS:
        print(f"selfsense: error: unknown command {cmd!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    mod_name, fn_name, _ = SUBCOMMANDS[cmd]
    from selfsense.determinism import single_thread_blas

    single_thread_blas()  # results do not depend on the BLAS thread count (docs/reproducibility.md)
    try:
        module = importlib.import_module(mod_name)
        return int(getattr(module, fn_name)(rest) or 0)
    except KeyboardInterrupt:
        print(f"selfsense {cmd}: interrupted", file=sys.stderr)
        return 130
    except _user_errors() as exc:
        if os.environ.get("SELFSENSE_TRACEBACK"):
            raise
        problems = getattr(exc, "problems", None)
        lines = [" ".join(str(p).split()) for p in problems] if problems else [_one_line(exc)]
        for line in lines:  # a contract error: one line per problem
            print(f"selfsense {cmd}: error: {_cap(line)}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - a bug, not bad input: still one line, exit 1
        if os.environ.get("SELFSENSE_TRACEBACK"):
            raise
        print(f"selfsense {cmd}: internal error ({type(exc).__name__}; SELFSENSE_TRACEBACK=1 shows the traceback): "
              f"{_cap(_one_line(exc))}", file=sys.stderr)
        return 1


def _cap(line: str, limit: int = 400) -> str:
    """A message line cut to ``limit`` characters (a 1 MB value never floods the terminal)."""
    return line if len(line) <= limit else line[:limit] + f"... ({len(line) - limit} more characters)"


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
