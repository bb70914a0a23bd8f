"""The ``selfsense`` command.

Each subcommand lives with the subpackage that owns it and is imported lazily, so that
``selfsense validate`` does not pay for numba or cvxpy start-up.

Subcommands
-----------
validate DATASET_DIR       check a raw dataset against the contract (selfsense.io.cli)
simulate ...               write a virtual-tweezer dataset (selfsense.sim.cli)
run ...                    run the Snakemake pipeline (selfsense.pipeline_cli)
gap diagnose|benchmark     sim-to-real gap diagnostic (selfsense.gap.cli)
ri ...                     RI vs modified-PI model comparison (selfsense.hysteresis.ri_cli)
estimate ...               chunked / streaming estimation of a long log (selfsense.sensing.cli)
"""
from __future__ import annotations

import importlib
import sys

#: subcommand -> (module, function); each function takes ``argv: list[str]`` and returns an exit code.
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "validate": ("selfsense.io.cli", "main"),
    "simulate": ("selfsense.sim.cli", "main"),
    "run": ("selfsense.pipeline_cli", "main"),
    "gap": ("selfsense.gap.cli", "main"),
    "ri": ("selfsense.hysteresis.ri_cli", "main"),
    "estimate": ("selfsense.sensing.cli", "main"),
    "fit-external": ("selfsense.hysteresis.external", "main"),
}


def _usage() -> str:
    lines = ["usage: selfsense <command> [args]", "", "commands:"]
    for name, (mod, _) in SUBCOMMANDS.items():
        lines.append(f"  {name:<14} ({mod})")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in {"-h", "--help"}:
        print(_usage())
        return 0 if argv else 2
    cmd, rest = argv[0], argv[1:]
    if cmd not in SUBCOMMANDS:
        print(f"selfsense: unknown command {cmd!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    mod_name, fn_name = SUBCOMMANDS[cmd]
    module = importlib.import_module(mod_name)
    return int(getattr(module, fn_name)(rest) or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
