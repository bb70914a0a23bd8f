"""``selfsense simulate``: write a virtual-tweezer dataset and its truth folder.

    selfsense simulate --scenario FILE.yaml --seed N --out DIR [--truth DIR] [--preset tweezer_sim|sample] [--force]

``--preset`` loads a packaged scenario (src/selfsense/sim/presets/); ``--scenario`` a YAML file.
Without ``--seed`` the scenario's own seed is used.  The truth folder defaults to ``<DIR>.truth``.
"""
from __future__ import annotations

import argparse
import sys

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="selfsense simulate", description=__doc__.split("\n\n")[0], allow_abbrev=False)
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--scenario", help="scenario YAML file")
    src.add_argument("--preset", choices=["tweezer_sim", "sample"], help="packaged scenario")
    ap.add_argument("--seed", type=int, default=None, help="seed (default: the scenario's)")
    ap.add_argument("--out", required=True, help="dataset folder to write (a new or empty folder; see --force)")
    ap.add_argument("--truth", default=None, help="truth folder (default <out>.truth)")
    ap.add_argument("--no-contributions", action="store_true", help="skip counterfactual effect columns")
    ap.add_argument("--force", action="store_true",
                    help="replace --out / --truth even if they hold a dataset or files selfsense did not write")
    a = ap.parse_args(argv)
    from pathlib import Path

    from selfsense.io import check_output_dir, output_lock

    from selfsense.sim.simulate import load_scenario, simulate_dataset
    try:
        # never replace a dataset or a folder selfsense did not write without --force (selfsense.io.outputs)
        truth = a.truth or str(Path(a.out).with_name(Path(a.out).name + ".truth"))
        inputs = [a.scenario] if a.scenario else []
        with output_lock(a.out), output_lock(truth, "--truth"):
            check_output_dir(a.out, inputs, force=a.force, allow_in_dataset=False)
            check_output_dir(truth, inputs + [a.out], force=a.force, what="--truth")
            sc = load_scenario(a.scenario if a.scenario else a.preset)
            out, truth = simulate_dataset(sc, a.seed, a.out, a.truth, contributions=not a.no_contributions)
    except (ValueError, OSError) as e:
        print(f"selfsense simulate: {e}", file=sys.stderr)
        return 2
    print(f"wrote {out} and {truth}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
