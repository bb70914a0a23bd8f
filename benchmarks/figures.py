#!/usr/bin/env python
"""One source for every measured figure that the README and docs/ quote.

    python benchmarks/figures.py            # regenerate benchmarks/FIGURES.md and the figure blocks in README/docs
    python benchmarks/figures.py --check    # exit 1 (naming the file and block) if any of them is out of date

Every figure is read from a committed benchmark output (never typed by hand): ``benchmarks/RESULTS.json``
(``benchmarks/run.py``: speed, memory, the cold pipeline and the Table 3 of that run), ``benchmarks/cross_device``
(``selfsense devices bench``), ``benchmarks/gap_stages`` (``selfsense gap blind``), ``benchmarks/stage_chain``
(``benchmarks/stage_chain.py``) and ``benchmarks/external`` (``selfsense fit-external``). Each row carries the
date of its measurement and the command that measures it. ``benchmarks/FIGURES.md`` holds them all; README.md and the
docs pages hold generated blocks between ``<!-- figures:NAME -->`` and ``<!-- /figures:NAME -->``, which this
script rewrites. ``tests/test_figures.py`` runs ``--check`` and also refuses figures of these kinds written outside
the blocks, so that the README, the docs and the benchmarks cannot disagree.
"""
from __future__ import annotations

import argparse
import csv
import json
import re
import statistics
import sys
from pathlib import Path
from collections.abc import Callable

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

#: when each committed benchmark output that records no date of its own was measured (update on re-measuring;
#: RESULTS.json records its own date)
DATES = {
    "cross_device": "2026-11-26",
    "first_contact_rate_kp": "2026-11-26",
    "whole_device": "2026-11-26",
    "whole_device_hold_rows": "2026-11-26",
    "whole_device_duhem_linear": "2026-11-26",
    "whole_device_relay_fix": "2026-11-27",
    "whole_device_adc18": "2026-11-27",
    "error_causes_fresh42": "2026-12-02",
    "error_causes_seeds0": "2026-12-02",
    "whole_device_charge_resolution": "2026-11-27",
    "hold_rows": "2026-11-26",
    "gap_stages": "2026-11-24",
    "gap_stages_16180": "2026-11-26",
    "gap_stages_31337": "2026-11-27",
    "gap_stages_20261201": "2026-12-01",
    "gap_stages_20261207": "2026-12-02",
    "gap_stages_20261223": "2026-12-06",
    "gap_stages_20261226": "2026-12-06",
    "gap_stages_5772156": "2026-12-06",
    "stress_first_20261206": "2026-12-02",
    "stress_wide_20261206": "2026-12-02",
    "stress_solve_20261206": "2026-12-03",
    "stress_first_20261208": "2026-12-03",
    "temperature_tip_20261215": "2026-12-05",
    "creep_member_8080": "2026-12-03",
    "creep_member_first_20261209": "2026-12-03",
    "creep_member_built_first_20261210": "2026-12-03",
    "stage_chain_tip_creep_off_fresh800": "2026-12-03",
    "stage_chain_tip_creep_fresh800": "2026-12-03",
    "stage_chain_drift_refit_fresh806": "2026-12-03",
    "stage_chain_current_fresh900": "2026-12-04",
    "stage_chain_lag_fresh1000": "2026-12-05",
    "stage_chain_lag_off_fresh1000": "2026-12-05",
    "whole_device_lag_fresh70": "2026-12-05",
    "whole_device_lag_gate_fresh70": "2026-12-05",
    "stage_chain_lag_gate_fresh1000": "2026-12-05",
    "whole_device_lag_off_fresh70": "2026-12-05",
    "whole_device_duhem_before_fresh72": "2026-12-05",
    "whole_device_duhem_joint_fresh72": "2026-12-05",
    "whole_device_duhem_joint_fresh70": "2026-12-05",
    "whole_device_joint_before_fresh74": "2026-12-05",
    "whole_device_joint_candidate_fresh74": "2026-12-05",
    "whole_device_current_fresh76": "2026-12-06",
    "whole_device_quantiser_laser_fresh76": "2026-12-06",
    "whole_device_quantiser_before_fresh79": "2026-12-06",
    "whole_device_quantiser_laser_fresh79": "2026-12-06",
    "whole_device_envelope_before_fresh82": "2026-12-06",
    "whole_device_envelope_after_fresh82": "2026-12-06",
    "whole_device_current_fresh85": "2026-12-07",
    "whole_device_current_fresh88": "2026-12-07",
    "whole_device_rest_sign_fresh88": "2026-12-07",
    "whole_device_reversible_fresh91": "2026-12-07",
    "whole_device_before_reversible_fresh91": "2026-12-07",
    "whole_device_reversible_fresh94": "2026-12-07",
    "whole_device_without_offset_drift_fresh91": "2026-12-07",
    "whole_device_without_leakage_fresh91": "2026-12-07",
    "whole_device_without_creep_fresh91": "2026-12-07",
    "whole_device_adc18_fresh91": "2026-12-07",
    "whole_device_adc18_drift_fresh91": "2026-12-07",
    "whole_device_weak_reference_fresh94": "2026-12-07",
    "whole_device_current_fresh97": "2026-12-07",
    "whole_device_current_drift_fresh97": "2026-12-07",
    "whole_device_current_fresh100": "2026-12-08",
    "whole_device_current_drift_fresh100": "2026-12-08",
    "creep_chain_first_20261211": "2026-12-03",
    "creep_chain_held_20261211": "2026-12-03",
    "gap_tip": "2026-11-24",
    "gap_tip_90210": "2026-11-26",
    "gap_tip_27182": "2026-11-26",
    "gap_tip_14142": "2026-11-26",
    "gap_tip_20261202": "2026-12-02",
    "gap_tip_20261213": "2026-12-04",
    "gap_tip_20261213_matched": "2026-12-04",
    "gap_tip_20261214": "2026-12-04",
    "gap_tip_20261216": "2026-12-05",
    "gap_tip_20261217": "2026-12-05",
    "gap_tip_20261218": "2026-12-05",
    "gap_tip_20261219": "2026-12-05",
    "gap_tip_20261221": "2026-12-06",
    "gap_tip_20261224": "2026-12-06",
    "gap_tip_20261227": "2026-12-06",
    "gap_tip_20261228": "2026-12-06",
    "gap_tip_20261232": "2026-12-08",
    "gap_tip_20261217_160": "2026-12-05",
    "gap_joint_20261203": "2026-12-02",
    "gap_joint_20261203_rule": "2026-12-02",
    "gap_joint_20261204": "2026-12-02",
    "gap_joint_20261205": "2026-12-02",
    "gap_joint_20261222": "2026-12-06",
    "stage_chain": "2026-11-26",
    "stage_chain_duhem_linear": "2026-11-26",
    "stage_chain_relay_bound": "2026-11-27",
    "stage_chain_relay_bound_fresh": "2026-11-27",
    "stage_chain_relay_bound_fresh400": "2026-11-27",
    "stage_chain_fold_majority": "2026-11-27",
    "stage_chain_fold_majority_fresh400": "2026-11-27",
    "whole_device_fold_majority": "2026-11-27",
    "stage_chain_holds_g": "2026-11-27",
    "stage_chain_holds_g_fresh300": "2026-11-27",
    "stage_chain_holds_g_fresh400": "2026-11-27",
    "stage_chain_corroborated": "2026-11-28",
    "stage_chain_corroborated_fresh300": "2026-11-28",
    "stage_chain_corroborated_fresh400": "2026-11-28",
    "stage_chain_holds_g_fresh500": "2026-11-28",
    "stage_chain_corroborated_fresh500": "2026-11-28",
    "stage_chain_before_selection_leak_fresh600": "2026-12-02",
    "stage_chain_selection_leak_fresh600": "2026-12-02",
    "stage_chain_selection_leak": "2026-12-02",
    "stage_chain_selection_leak_fresh500": "2026-12-02",
    "stage_chain_fold_starts": "2026-12-02",
    "stage_chain_current_seeds0_5": "2026-12-04",
    "stage_chain_before_fold_starts_fresh700": "2026-12-02",
    "stage_chain_fold_starts_fresh700": "2026-12-02",
    "whole_device_holds_g": "2026-11-27",
    "whole_device_quantiser": "2026-11-27",
    "whole_device_quantiser_bound": "2026-11-27",
    "tip_amplifier": "2026-11-26",
    "tip_stress": "2026-11-26",
    "tip_preload": "2026-11-27",
    "amplifier_blind": "2026-11-26",
    "absorption_blind": "2026-11-26",
    "temperature_blind": "2026-12-05",
    "stress_blind": "2026-11-28",
    "absorption_null": "2026-11-26",
    "absorption_member": "2026-11-26",
    "external": "2026-11-24",
}
COMMANDS = {
    "results": "python benchmarks/run.py --out benchmarks/RESULTS.md",
    "cross_device": "selfsense devices bench --n 10 --jobs 2 --out benchmarks/cross_device",
    "first_contact_rate_kp": "selfsense devices bench --n 10 --families rate_kp --jobs 2 --protocol {protocol} "
                             "--out benchmarks/cross_device/first_contact_rate_kp/{protocol}",
    "whole_device": "selfsense devices bench --n 10 --jobs 2 --protocol thesis --randomise device "
                    "--out benchmarks/cross_device/whole_device/thesis",
    "whole_device_relay_fix": "selfsense devices bench --n 5 --jobs 2 --protocol thesis --randomise device "
                              "--out benchmarks/cross_device/whole_device/thesis_relay_fix",
    "whole_device_charge_resolution": "selfsense devices bench --n 10 --jobs 2 --protocol thesis --randomise device "
                                      "--out benchmarks/cross_device/whole_device/thesis_charge_resolution",
    "whole_device_fold_majority": "selfsense devices bench --n 10 --jobs 2 --protocol thesis --randomise device "
                                  "--out benchmarks/cross_device/whole_device/thesis_fold_majority",
    "whole_device_holds_g": "selfsense devices bench --n 10 --jobs 2 --protocol thesis --randomise device "
                            "--out benchmarks/cross_device/whole_device/thesis_holds_g",
    # the quantiser member switched on (config quantiser: auto; off by default): the 27 devices on which it is adopted
    # scored again (their records deleted from a copy of thesis_holds_g, the folder resumed); the other 73 records are
    # carried over: the member leaves their fit unchanged
    "whole_device_quantiser": "selfsense devices bench --n 10 --jobs 2 --protocol thesis --randomise device "
                              "--configfile benchmarks/cross_device/whole_device/thesis_quantiser/config.yaml "
                              "--out benchmarks/cross_device/whole_device/thesis_quantiser",
    # the quantiser member with the bound gate (a current at half a step over R is not adopted): a copy of
    # thesis_quantiser with the records of the 8 devices whose search ends at the bound deleted and the folder resumed
    # (they are now fitted as with the member off); the other 92 records are carried over unchanged
    "whole_device_quantiser_bound": "selfsense devices bench --n 10 --jobs 2 --protocol thesis --randomise device "
                                    "--configfile benchmarks/cross_device/whole_device/thesis_quantiser_bound/config.yaml "
                                    "--out benchmarks/cross_device/whole_device/thesis_quantiser_bound",
    "error_causes_fresh42": "python benchmarks/error_causes.py benchmarks/cross_device/whole_device/fold_starts_fresh42 "
                            "--out benchmarks/cross_device/whole_device/fold_starts_fresh42/error_causes.md (records: "
                            "selfsense devices bench --n 2 --first-seed 42 --jobs 1 --protocol thesis --randomise "
                            "device --out benchmarks/cross_device/whole_device/fold_starts_fresh42)",
    "error_causes_seeds0": "python benchmarks/error_causes.py benchmarks/cross_device/whole_device/current_seeds0 "
                           "--out benchmarks/cross_device/whole_device/current_seeds0/error_causes.md (records: "
                           "selfsense devices bench --n 2 --jobs 2 --protocol thesis --randomise device --out "
                           "benchmarks/cross_device/whole_device/current_seeds0)",
    "whole_device_adc18": "selfsense devices bench --n 5 --jobs 2 --protocol thesis --randomise device "
                          "--set adc_bits=18 --out benchmarks/cross_device/whole_device/thesis_adc18",
    "whole_device_hold_rows": "selfsense devices bench --n 10 --jobs 2 --protocol thesis --randomise device "
                              "--out benchmarks/cross_device/whole_device/thesis_hold_rows",
    # the devices rescored after the Duhem model got its own linear term, into one folder: clean Bouc-Wen 10 devices,
    # then the other four families 5 each (--jobs 1); drift Bouc-Wen, then Jiles-Atherton, 10 devices each (--jobs 2:
    # the records do not depend on it, WHOLE_DUHEM_JOBS)
    "whole_device_duhem_linear": "selfsense devices bench --n {n} --families {families} --presets {preset} --jobs {jobs} "
                                 "--protocol thesis --randomise device "
                                 "--out benchmarks/cross_device/whole_device/thesis_hold_rows_duhem_linear",
    "hold_rows": "python benchmarks/hold_rows.py --seeds 0-2 --holds 0,8 --jobs 2 --out benchmarks/hold_rows",
    "gap_stages": "selfsense gap blind --n 1000 --seed 7 --jobs 2 --out benchmarks/gap_stages",
    "gap_stages_16180": "selfsense gap blind --n 1000 --seed 16180 --jobs 1 --out benchmarks/gap_stages/seed_16180",
    "gap_stages_31337": "selfsense gap blind --n 1000 --seed 31337 --jobs 2 --out benchmarks/gap_stages/seed_31337",
    # the stand-in's H a Preisach operator with creep (the blocked stage's nominal), thresholds recalibrated
    "gap_stages_20261201": "selfsense gap blind --n 1000 --seed 20261201 --jobs 2 "
                           "--out benchmarks/gap_stages/seed_20261201",
    "gap_stages_20261207": "selfsense gap blind --n 1000 --seed 20261207 --jobs 2 "
                           "--out benchmarks/gap_stages/seed_20261207",
    "gap_stages_20261223": "selfsense gap blind --n 1000 --seed 20261223 --jobs 2 "
                           "--out benchmarks/gap_stages/seed_20261223",
    "gap_stages_20261226": "selfsense gap blind --n 1000 --seed 20261226 --jobs 2 "
                           "--out benchmarks/gap_stages/seed_20261226",
    "gap_stages_5772156": "selfsense gap blind --n 1000 --seed 5772156 --jobs 2 "
                          "--out benchmarks/gap_stages/seed_5772156",
    "stress_first_20261206": "python benchmarks/tip_cases.py --seed 20261206 --cases 1,65,102,104,111,124,135,146 "
                             "--jobs 1 --campaign none --out benchmarks/gap_tip/stress_first_20261206.md",
    "stress_wide_20261206": "python benchmarks/tip_cases.py --seed 20261206 --cases 104 --jobs 1 --campaign none "
                            "--out benchmarks/gap_tip/stress_wide_20261206.md",
    "stress_solve_20261206": "python benchmarks/tip_cases.py --seed 20261206 --cases 1,65,102,104,111,124,135,146 "
                             "--jobs 2 --campaign none --out benchmarks/gap_tip/stress_solve_20261206.md",
    "creep_member_8080": "python benchmarks/creep_member.py --seed 8080 --cases 25,33,99,155,188,271,316 --jobs 2 "
                         "--out benchmarks/gap_tip/creep_member_8080.md",
    "creep_member_first_20261209": "python benchmarks/creep_member.py --seed 20261209 --cases "
                                   "29,32,43,46,87,97,107,119 --jobs 2 "
                                   "--out benchmarks/gap_tip/creep_member_first_20261209.md",
    "stress_first_20261208": "python benchmarks/tip_cases.py --seed 20261208 --cases 39,40,43,64,65,66,86,91,106,132 "
                             "--jobs 2 --campaign none --out benchmarks/gap_tip/stress_first_20261208.md",
    "temperature_tip_20261215": "python benchmarks/tip_cases.py --seed 20261215 --cases 0,3,14,25,27,30,53,59 "
                                "--jobs 2 --campaign none --out benchmarks/gap_tip/temperature_tip_20261215.md",
    "gap_tip": "selfsense gap blind --tip --n 80 --seed 4711 --jobs 2 --out benchmarks/gap_tip",
    # the tip tier after the simulator's stress fix, with a carried chain member scored by its own contribution
    "gap_tip_90210": "selfsense gap blind --tip --n 120 --seed 90210 --jobs 2 --out benchmarks/gap_tip/seed_90210",
    # the same tier on another new seed with the absorption member of the charge link
    "gap_tip_27182": "selfsense gap blind --tip --n 120 --seed 27182 --jobs 2 --out benchmarks/gap_tip/seed_27182",
    "gap_tip_14142": "selfsense gap blind --tip --n 240 --seed 14142 --jobs 2 --out benchmarks/gap_tip/seed_14142",
    # the stage diagnosis with the Preisach stand-in H (its first tip tier)
    "gap_tip_20261202": "selfsense gap blind --tip --n 80 --seed 20261202 --jobs 2 --out benchmarks/gap_tip/seed_20261202",
    "gap_tip_20261213": "selfsense gap blind --tip --n 80 --seed 20261213 --jobs 1 --out benchmarks/gap_tip/seed_20261213",
    "gap_tip_20261214": "selfsense gap blind --tip --n 80 --seed 20261214 --jobs 1 --out benchmarks/gap_tip/seed_20261214",
    "gap_tip_20261216": "selfsense gap blind --tip --n 80 --seed 20261216 --jobs 1 --out benchmarks/gap_tip/seed_20261216",
    "gap_tip_20261217": "selfsense gap blind --tip --n 80 --seed 20261217 --jobs 1 --out benchmarks/gap_tip/seed_20261217",
    "gap_tip_20261218": "selfsense gap blind --tip --n 80 --seed 20261218 --jobs 1 --out benchmarks/gap_tip/seed_20261218",
    "gap_tip_20261219": "selfsense gap blind --tip --n 80 --seed 20261219 --jobs 2 --out benchmarks/gap_tip/seed_20261219",
    "gap_tip_20261221": "selfsense gap blind --tip --n 80 --seed 20261221 --jobs 2 --out benchmarks/gap_tip/seed_20261221 "
                        "(the code before the widened interval), then python benchmarks/interval_calibration.py --apply "
                        "benchmarks/gap_tip/seed_20261221 --out benchmarks/gap_tip/seed_20261221",
    "gap_tip_20261224": "selfsense gap blind --tip --n 80 --seed 20261224 --jobs 2 --out benchmarks/gap_tip/seed_20261224",
    "gap_tip_20261227": "selfsense gap blind --tip --n 80 --seed 20261227 --jobs 2 --out benchmarks/gap_tip/seed_20261227",
    "gap_tip_20261228": "selfsense gap blind --tip --n 80 --seed 20261228 --jobs 2 --out benchmarks/gap_tip/seed_20261228",
    "gap_tip_20261232": "python benchmarks/tip_cases.py --seed 20261232 --cases 0,1,...,49 --jobs 2 --campaign none "
                        "--out tip_0_49.md, the same for cases 50-99, 100-149 and 150-199, cases 200-299 (a run "
                        "of 200-299 stopped at 224 and resumed from its tip_200_299.partial.jsonl) and cases 300-348 "
                        "of a run of 300-399 stopped there (code 17728e2: the estimator and the diagnostic unchanged "
                        "since), pooled by python benchmarks/tip_pool.py --records tip_0_224.jsonl.gz (cases 0-224, "
                        "pooled from the first parts the same way) tip_225_299.jsonl.gz tip_300_348.jsonl.gz --out "
                        "benchmarks/gap_tip/seed_20261232",
    # the same seed's cases 80-159 (benchmarks/tip_cases.py), pooled with its first 80 into one 160-case tier
    "gap_tip_20261217_160": "python benchmarks/tip_pool.py --records benchmarks/gap_tip/seed_20261217/tip_cases.jsonl.gz "
                            "ext_80_159.jsonl.gz --out benchmarks/gap_tip/seed_20261217_160 (cases 80-159 by python "
                            "benchmarks/tip_cases.py --seed 20261217 --cases 80,...,159 --jobs 2 --campaign none)",
    "gap_tip_20261213_matched": "python benchmarks/tip_matched_twin.py --records benchmarks/gap_tip/seed_20261213 "
                                "--out benchmarks/gap_tip/seed_20261213_matched",
    # the joint tip tier (cases with 2-3 effects, the all-together prediction against the twin without them)
    "gap_joint_20261203": "python benchmarks/tip_joint.py --seed 20261203 --n 40 --jobs 1 --out "
                          "benchmarks/gap_tip/joint_20261203",
    "gap_joint_20261203_rule": "python benchmarks/tip_joint.py --seed 20261203 --n 40 --jobs 1 --out "
                               "benchmarks/gap_tip/joint_20261203_rule",
    "gap_joint_20261204": "python benchmarks/tip_joint.py --seed 20261204 --n 40 --jobs 1 --out "
                          "benchmarks/gap_tip/joint_20261204",
    "gap_joint_20261205": "python benchmarks/tip_joint.py --seed 20261205 --n 20 --jobs 1 --out "
                          "benchmarks/gap_tip/joint_20261205",
    "gap_joint_20261222": "python benchmarks/tip_joint.py --seed 20261222 --n 20 --jobs 2 --out "
                          "benchmarks/gap_tip/joint_20261222",
    "stage_chain": "python benchmarks/stage_chain.py devices --seeds 0-5 --hold-s 0 --out benchmarks/stage_chain/thesis",
    "stage_chain_duhem_linear": "python benchmarks/stage_chain.py devices --families {families} --seeds 0-5 --hold-s 0 "
                                "--out benchmarks/stage_chain/thesis_duhem_linear",
    "stage_chain_relay_bound": "python benchmarks/stage_chain.py devices --seeds 0-5 --hold-s 0 "
                               "--out benchmarks/stage_chain/thesis_relay_bound",
    "stage_chain_relay_bound_fresh": "python benchmarks/stage_chain.py devices --seeds 300-305 --hold-s 0 "
                                     "--out benchmarks/stage_chain/thesis_relay_bound_fresh",
    # the code before the leakage fold majority (commit 6bad672) on seeds it never saw, as the "before" of the first
    # contact below
    "stage_chain_relay_bound_fresh400": "python benchmarks/stage_chain.py devices --seeds 400-405 --hold-s 0 "
                                        "--out benchmarks/stage_chain/thesis_relay_bound_fresh400",
    "stage_chain_fold_majority": "python benchmarks/stage_chain.py devices --seeds 0-5 --hold-s 0 "
                                 "--out benchmarks/stage_chain/fold_majority",
    "stage_chain_fold_majority_fresh400": "python benchmarks/stage_chain.py devices --seeds 400-405 --hold-s 0 "
                                          "--out benchmarks/stage_chain/fold_majority_fresh400",
    "stage_chain_holds_g": "python benchmarks/stage_chain.py devices --seeds 0-5 --hold-s 0 "
                           "--out benchmarks/stage_chain/holds_g",
    "stage_chain_holds_g_fresh300": "python benchmarks/stage_chain.py devices --seeds 300-305 --hold-s 0 "
                                    "--out benchmarks/stage_chain/holds_g_fresh300",
    "stage_chain_holds_g_fresh400": "python benchmarks/stage_chain.py devices --seeds 400-405 --hold-s 0 "
                                    "--out benchmarks/stage_chain/holds_g_fresh400",
    "stage_chain_corroborated": "python benchmarks/stage_chain.py devices --seeds 0-5 --hold-s 0 "
                                "--out benchmarks/stage_chain/corroborated",
    "stage_chain_corroborated_fresh300": "python benchmarks/stage_chain.py devices --seeds 300-305 --hold-s 0 "
                                         "--out benchmarks/stage_chain/corroborated_fresh300",
    "stage_chain_corroborated_fresh400": "python benchmarks/stage_chain.py devices --seeds 400-405 --hold-s 0 "
                                         "--out benchmarks/stage_chain/corroborated_fresh400",
    "stage_chain_holds_g_fresh500": "python benchmarks/stage_chain.py devices --seeds 500-505 --hold-s 0 "
                                    "--out benchmarks/stage_chain/holds_g_fresh500 (the code before the leakage "
                                    "corroboration rule)",
    "stage_chain_corroborated_fresh500": "python benchmarks/stage_chain.py devices --seeds 500-505 --hold-s 0 "
                                         "--out benchmarks/stage_chain/corroborated_fresh500",
    "stage_chain_before_selection_leak_fresh600": "python benchmarks/stage_chain.py devices --seeds 600-605 --hold-s 0 "
                                                  "--out benchmarks/stage_chain/before_selection_leak_fresh600 (the "
                                                  "code before the leakage-by-selection rule)",
    "stage_chain_selection_leak_fresh600": "python benchmarks/stage_chain.py devices --seeds 600-605 --hold-s 0 "
                                           "--out benchmarks/stage_chain/selection_leak_fresh600",
    "stage_chain_selection_leak": "python benchmarks/stage_chain.py devices --seeds 0-5 --hold-s 0 "
                                  "--out benchmarks/stage_chain/selection_leak",
    "stage_chain_selection_leak_fresh500": "python benchmarks/stage_chain.py devices --seeds 500-505 --hold-s 0 "
                                           "--out benchmarks/stage_chain/selection_leak_fresh500",
    "stage_chain_fold_starts": "python benchmarks/stage_chain.py devices --seeds 0-5 --hold-s 0 "
                               "--out benchmarks/stage_chain/fold_starts",
    "stage_chain_current_seeds0_5": "python benchmarks/stage_chain.py devices --seeds 0-5 --hold-s 0 "
                                    "--out benchmarks/stage_chain/current_seeds0_5",
    "stage_chain_before_fold_starts_fresh700": "python benchmarks/stage_chain.py devices --seeds 700-702 --hold-s 0 "
                                               "--out benchmarks/stage_chain/before_fold_starts_fresh700 (the code "
                                               "of commit e0d11bc)",
    "stage_chain_fold_starts_fresh700": "python benchmarks/stage_chain.py devices --seeds 700-702 --hold-s 0 "
                                        "--out benchmarks/stage_chain/fold_starts_fresh700",
    "stage_chain_tip_creep_off_fresh800": "python benchmarks/stage_chain.py devices --seeds 800-803 --hold-s 0 "
                                          "--members '{{\"tip_creep\": \"off\"}}' "
                                          "--out benchmarks/stage_chain/tip_creep_off_fresh800",
    "stage_chain_tip_creep_fresh800": "python benchmarks/stage_chain.py devices --seeds 800-803 --hold-s 0 "
                                      "--out benchmarks/stage_chain/tip_creep_fresh800",
    "stage_chain_drift_refit_fresh806": "python benchmarks/stage_chain.py devices --seeds 806-809 --hold-s 0 "
                                        "--out benchmarks/stage_chain/drift_refit_fresh806",
    "stage_chain_current_fresh900": "python benchmarks/stage_chain.py devices --seeds 900-905 --hold-s 0 "
                                    "--out benchmarks/stage_chain/current_fresh900",
    "stage_chain_lag_fresh1000": "python benchmarks/stage_chain.py devices --seeds 1000-1002 --hold-s 0 "
                                 "--out benchmarks/stage_chain/lag_fresh1000",
    "stage_chain_lag_off_fresh1000": "python benchmarks/stage_chain.py devices --seeds 1000-1002 --hold-s 0 "
                                     "--members '{{\"amplifier_lag\": \"off\"}}' "
                                     "--out benchmarks/stage_chain/lag_off_fresh1000",
    "whole_device_lag_fresh70": "selfsense devices bench --n 2 --first-seed 70 --jobs 2 --protocol thesis "
                                "--randomise device --out benchmarks/cross_device/whole_device/lag_fresh70",
    "whole_device_lag_gate_fresh70": "selfsense devices bench --n 2 --first-seed 70 --jobs 1 --protocol thesis "
                                     "--randomise device --out benchmarks/cross_device/whole_device/lag_gate_fresh70 "
                                     "(resumed from a copy of lag_fresh70 without the device that had adopted the "
                                     "member)",
    "stage_chain_lag_gate_fresh1000": "python benchmarks/stage_chain.py devices --seeds 1000-1002 --hold-s 0 "
                                      "--out benchmarks/stage_chain/lag_gate_fresh1000 (resumed from a copy of "
                                      "lag_fresh1000 without the five devices that had adopted the member)",
    "whole_device_duhem_before_fresh72": "selfsense devices bench --n 2 --first-seed 72 --jobs 1 --protocol thesis "
                                         "--randomise device --out "
                                         "benchmarks/cross_device/whole_device/duhem_before_fresh72",
    "whole_device_duhem_joint_fresh72": "selfsense devices bench --n 2 --first-seed 72 --jobs 1 --protocol thesis "
                                        "--randomise device --out benchmarks/cross_device/whole_device/duhem_joint_fresh72 "
                                        "(with the rejected joint hold search of the Duhem map)",
    "whole_device_duhem_joint_fresh70": "selfsense devices bench --n 2 --first-seed 70 --jobs 1 --protocol thesis "
                                        "--randomise device --out benchmarks/cross_device/whole_device/duhem_joint_fresh70 "
                                        "(with the rejected joint hold search of the Duhem map)",
    "whole_device_joint_before_fresh74": "selfsense devices bench --n 2 --first-seed 74 --jobs 1 --protocol thesis "
                                         "--randomise device --out "
                                         "benchmarks/cross_device/whole_device/joint_before_fresh74 (the code before "
                                         "the joint hold candidate)",
    "whole_device_joint_candidate_fresh74": "selfsense devices bench --n 2 --first-seed 74 --jobs 1 --protocol thesis "
                                            "--randomise device --out "
                                            "benchmarks/cross_device/whole_device/joint_candidate_fresh74",
    "whole_device_current_fresh76": "selfsense devices bench --n 3 --first-seed 76 --jobs 2 --protocol thesis "
                                    "--randomise device --out benchmarks/cross_device/whole_device/current_fresh76 "
                                    "(the code before the quantiser member on the free-tip laser)",
    "whole_device_quantiser_laser_fresh76": "selfsense devices bench --n 3 --first-seed 76 --jobs 2 --protocol thesis "
                                            "--randomise device --configfile quantiser_auto.yaml --out "
                                            "benchmarks/cross_device/whole_device/quantiser_laser_fresh76 "
                                            "(quantiser_auto.yaml: calibration: quantiser: auto, the default since)",
    "whole_device_quantiser_before_fresh79": "selfsense devices bench --n 3 --first-seed 79 --jobs 1 --protocol thesis "
                                             "--randomise device --out "
                                             "benchmarks/cross_device/whole_device/quantiser_before_fresh79 (the code "
                                             "before the quantiser member on the free-tip laser)",
    "whole_device_quantiser_laser_fresh79": "selfsense devices bench --n 3 --first-seed 79 --jobs 2 --protocol thesis "
                                            "--randomise device --out "
                                            "benchmarks/cross_device/whole_device/quantiser_laser_fresh79",
    "whole_device_envelope_before_fresh82": "selfsense devices bench --n 3 --first-seed 82 --jobs 2 --protocol thesis "
                                            "--randomise device --out "
                                            "benchmarks/cross_device/whole_device/envelope_before_fresh82 (the code "
                                            "before the major-loop check and the holds' leakage bound)",
    "whole_device_envelope_after_fresh82": "selfsense devices bench --n 3 --first-seed 82 --jobs 2 --protocol thesis "
                                           "--randomise device --out "
                                           "benchmarks/cross_device/whole_device/envelope_after_fresh82 (made with "
                                           "4ce9fac, before the bound's negative-estimate refusal)",
    "whole_device_current_fresh85": "selfsense devices bench --n 3 --first-seed 85 --jobs 2 --protocol thesis "
                                    "--randomise device --out benchmarks/cross_device/whole_device/current_fresh85",
    "whole_device_current_fresh88": "selfsense devices bench --n 3 --first-seed 88 --jobs 2 --protocol thesis "
                                    "--randomise device --out benchmarks/cross_device/whole_device/current_fresh88",
    "whole_device_before_reversible_fresh91": "selfsense devices bench --n 3 --first-seed 91 --jobs 2 --protocol "
                                              "thesis --randomise device --out "
                                              "benchmarks/cross_device/whole_device/before_reversible_fresh91 (made "
                                              "with 88dade5, the code before the Preisach reversible part)",
    "whole_device_reversible_fresh94": "selfsense devices bench --n 3 --first-seed 94 --jobs 2 --protocol thesis "
                                       "--randomise device --out "
                                       "benchmarks/cross_device/whole_device/reversible_fresh94",
    "whole_device_without_offset_drift_fresh91": "selfsense devices bench --n 3 --first-seed 91 --presets drift --jobs 2 "
                                                 "--protocol thesis --randomise device --without offset_drift --out "
                                                 "benchmarks/cross_device/whole_device/without_offset_drift_fresh91",
    "whole_device_without_leakage_fresh91": "selfsense devices bench --n 3 --first-seed 91 --presets drift --jobs 2 "
                                            "--protocol thesis --randomise device --without leakage --out "
                                            "benchmarks/cross_device/whole_device/without_leakage_fresh91",
    "whole_device_without_creep_fresh91": "selfsense devices bench --n 3 --first-seed 91 --presets drift --jobs 2 "
                                          "--protocol thesis --randomise device --without creep --out "
                                          "benchmarks/cross_device/whole_device/without_creep_fresh91",
    "whole_device_adc18_fresh91": "selfsense devices bench --n 6 --first-seed 91 --presets clean --jobs 2 --protocol "
                                  "thesis --randomise device --set adc_bits=18 --out "
                                  "benchmarks/cross_device/whole_device/adc18_fresh91",
    "whole_device_adc18_drift_fresh91": "selfsense devices bench --n 6 --first-seed 91 --presets drift --jobs 2 "
                                        "--protocol thesis --randomise device --set adc_bits=18 --out "
                                        "benchmarks/cross_device/whole_device/adc18_drift_fresh91",
    "whole_device_current_fresh97": "selfsense devices bench --n 3 --first-seed 97 --presets clean --jobs 1 "
                                    "--protocol thesis --randomise device --out "
                                    "benchmarks/cross_device/whole_device/current_fresh97",
    "whole_device_current_drift_fresh97": "selfsense devices bench --n 3 --first-seed 97 --presets drift --jobs 2 "
                                          "--protocol thesis --randomise device --out "
                                          "benchmarks/cross_device/whole_device/current_drift_fresh97",
    "whole_device_current_fresh100": "selfsense devices bench --n 2 --first-seed 100 --presets clean --jobs 1 "
                                     "--protocol thesis --randomise device --out "
                                     "benchmarks/cross_device/whole_device/current_fresh100 (its two rate-dependent KP "
                                     "devices, refused by the data contract at first contact, scored again by the same "
                                     "command with --families rate_kp after rig.yaml amplifier_current_limit_a)",
    "whole_device_current_drift_fresh100": "selfsense devices bench --n 2 --first-seed 100 --presets drift --jobs 1 "
                                           "--protocol thesis --randomise device --out "
                                           "benchmarks/cross_device/whole_device/current_drift_fresh100",
    "whole_device_weak_reference_fresh94": "selfsense devices run --family rate_kp --preset PRESET --seed 96 "
                                           "--protocol thesis --randomise device --out benchmarks/cross_device/"
                                           "whole_device/weak_reference_fresh94/records/rate_kp_PRESET_96.json "
                                           "(PRESET clean and drift), then selfsense devices table on the two records",
    "whole_device_reversible_fresh91": "selfsense devices bench --n 3 --first-seed 91 --jobs 2 --protocol thesis "
                                       "--randomise device --out "
                                       "benchmarks/cross_device/whole_device/reversible_fresh91",
    "whole_device_rest_sign_fresh88": "selfsense devices bench --n 3 --first-seed 88 --jobs 2 --protocol thesis "
                                      "--randomise device --out benchmarks/cross_device/whole_device/rest_sign_fresh88 "
                                      "(made with benchmarks/cross_device/whole_device/rest_sign_fresh88/rule.diff "
                                      "applied to 2c48cc2: a rule not in the code)",
    "whole_device_lag_off_fresh70": "selfsense devices bench --n 2 --first-seed 70 --jobs 2 --protocol thesis "
                                    "--randomise device --member amplifier_lag=off "
                                    "--out benchmarks/cross_device/whole_device/lag_off_fresh70",
    "creep_chain_first_20261211": "python benchmarks/tip_cases.py --seed 20261211 --cases 0,1,37,51,53,67,76,91 "
                                  "--jobs 2 --out benchmarks/gap_tip/creep_chain_first_20261211.md",
    "creep_chain_held_20261211": "python benchmarks/tip_cases.py --seed 20261211 --cases 0,1,37,51,53,67,76,91 "
                                 "--jobs 2 --out benchmarks/gap_tip/creep_chain_held_20261211.md",
    "creep_member_built_first_20261210": "python benchmarks/creep_member.py --member --seed 20261210 --cases "
                                         "3,16,35,64,81,85,93,96 --jobs 2 "
                                         "--out benchmarks/gap_tip/creep_member_built_first_20261210.md",
    "stage_tip": "python benchmarks/stage_chain.py tip --cases 40 --seed 2026 --out benchmarks/stage_chain/tip",
    "tip_amplifier": "python benchmarks/tip_cases.py --seed 4711 --cases 60,44,12,38,66,43,13,5,70 --jobs 2 "
                     "--out benchmarks/gap_tip/amplifier_member.md",
    "amplifier_blind": "python benchmarks/member_ab.py --member amplifier --effect rate.amplifier --seed 20261126 "
                       "--n 8 --jobs 2 --out benchmarks/gap_tip/amplifier_blind.md",
    "stress_blind": "python benchmarks/member_ab.py --member stress --effect load.stress_hysteresis --seed 20261128 "
                    "--n 8 --jobs 2 --out benchmarks/gap_tip/stress_blind.md",
    "absorption_blind": "python benchmarks/member_ab.py --member absorption --effect slow.absorption --seed 31415 "
                        "--n 8 --jobs 2 --out benchmarks/gap_tip/absorption_blind.md",
    "temperature_blind": "python benchmarks/member_ab.py --member temperature --effect slow.temperature --seed 20261215 "
                         "--n 8 --jobs 2 --out benchmarks/gap_tip/temperature_blind.md",
    "absorption_member": "python benchmarks/tip_cases.py --seed 90210 --cases 4,14,21,45,49,50,73,83,91,97,103,105 "
                         "--jobs 2 --campaign benchmarks/gap_tip/seed_90210/tip_cases.jsonl.gz "
                         "--out benchmarks/gap_tip/absorption_member_90210.md",
    "absorption_null": "python benchmarks/absorption_null.py --families preisach,gpi,bouc_wen,jiles_atherton,rate_kp "
                       "--seeds 0-5 --out benchmarks/gap_tip/absorption_null.md",
    "tip_preload": "python benchmarks/tip_cases.py --seed 14142 --cases 8,11,15,43,62,130,151,200 --jobs 2 "
                   "--campaign benchmarks/gap_tip/seed_14142/tip_cases.jsonl.gz --out benchmarks/gap_tip/preload_relay_fix.md",
    "tip_stress": "python benchmarks/tip_cases.py --seed 4711 --cases 1,18,24,25,37,56,71,74 --jobs 1 "
                  "--out benchmarks/gap_tip/stress_simfix.md",
    "external": "selfsense fit-external --data-dir DIR --out benchmarks/external/fit_external.md",
}
FAMILY = {"preisach": "Preisach", "gpi": "generalised PI", "jiles_atherton": "Jiles-Atherton",
          "bouc_wen": "Bouc-Wen", "rate_kp": "rate-dependent KP"}
BLOCK = re.compile(r"(<!-- figures:(?P<name>[a-z_]+) -->\n)(?P<body>.*?)(<!-- /figures:(?P=name) -->)", re.S)
#: the pages that hold figure blocks
PAGES = ["README.md", "docs/benchmarks.md", "docs/cross_device.md", "docs/gap.md", "docs/hysteresis.md",
         "docs/realtime.md"]


class Fig:
    """One measured figure: what, value (as printed), target, status, source file, command, date. ``history``: an
    intermediate scoring of a benchmark (neither its first contact nor the current code's), listed in
    benchmarks/FIGURES.md and the docs pages but not in the README's table."""

    def __init__(self, label, value, target="", status="", source="", command="", date="", history=False):
        self.label, self.value, self.target, self.status = label, value, target, status
        self.source, self.command, self.date, self.history = source, command, date, history

    def row(self, with_source: bool = True) -> str:
        cells = [self.label, self.value, self.target, self.status]
        if with_source:
            cells += [f"[{self.source}]({self.source})" if self.source else "", f"`{self.command}`", self.date]
        return "| " + " | ".join(cells) + " |"


def _met(ok: bool) -> str:
    return "met" if ok else "**missed**"


def _read_json(rel: str) -> dict:
    p = ROOT / rel
    if not p.exists():
        raise SystemExit(f"benchmarks/figures.py: {rel} not found (run: {COMMANDS['results']})")
    return json.loads(p.read_text())


# --------------------------------------------------------------------------------------------------------- sources
def results_figures() -> dict[str, list[Fig]]:
    """Speed, memory, pipeline and the bundled Table 3, from benchmarks/RESULTS.json (benchmarks/run.py)."""
    r = _read_json("benchmarks/RESULTS.json")
    src, cmd, date = "benchmarks/RESULTS.md", r.get("command", COMMANDS["results"]), r["machine"]["date"][:10]
    if r.get("quick"):
        raise SystemExit("benchmarks/figures.py: benchmarks/RESULTS.json is from a --quick run; the quoted figures "
                         "come from the full run: " + COMMANDS["results"])
    F = lambda *a, **k: Fig(*a, source=src, command=cmd, date=date, **k)  # noqa: E731
    a, b, c, d, f = r["a"], r["b"], r["c"], r["d"], r["f"]
    speed = [
        F("modified PI operator with creep (15 play, 15 superposition, 15 x 4 creep), one core",
          f"{a['rate_pkg'] / 1e6:.1f} M samples/s ({a['ratio_pkg']:.0f}x the NumPy reference)",
          ">= 10 M samples/s and >= 100x", _met(a["ok"])),
        F("streaming estimator, per-sample `step()`", f"{b['step_us']:.2f} us/sample", "<= 10 us",
          _met(b["step_us"] <= 10)),
        F("streaming estimator, block `process()`", f"{b['rate_block'] / 1e6:.1f} M samples/s", ">= 1 M samples/s",
          _met(b["rate_block"] >= 1e6)),
        *[F(f"streaming estimator, the pipeline's default model on `tweezer_sim` ({k['model']}), blocks of 100 "
            "samples", f"{k['us_100']:.2f} us/sample (step {k['us_step']:.0f} us)", "<= 1 us", _met(k["us_100"] <= 1.0))
          for k in b.get("kinds", []) if k["label"].startswith("default") and "us_100" in k],
        *[F(f"generated C (`selfsense export-c`), the pipeline's default model on `tweezer_sim` ({k['model']})",
            f"{k['c_ns'] / 1e3:.3f} us/sample", "<= 0.2 us", _met(k["c_ns"] <= 200))
          for k in b.get("kinds", []) if k["label"].startswith("default") and "c_ns" in k],
        F("stream equal to the batch pipeline", f"{max(b['err_dx'], b['err_f']):.0e} of range", "<= 1e-12",
          _met(max(b["err_dx"], b["err_f"]) <= 1e-12)),
        F("QP calibration of a 60,000-sample trial (modified PI)", f"{c['t_total']:.2f} s", "<= 1 s", _met(c["ok"])),
        F(f"chunked `selfsense estimate` of a {f['n'] / 1e6:.0f} M-sample log", f"peak RSS {f['rss_gb']:.2f} GB",
          "< 2 GB", _met(f["ok"])),
    ]
    pipe, bundled = [], []
    if d.get("available"):
        pipe.append(F("cold pipeline on `tweezer_sim`, `--cores 2`, numba cache warm (whole `snakemake` process)",
                      f"{d['wall_s']:.1f} s wall ({d['snakemake_s']:.1f} s by Snakemake's clock)", "<= 15 s wall",
                      _met(d["wall_s"] <= 15.0)))
        t3 = d["table3_rows"]
        bundled.append(F("Table 3 with the default settings (validation trials), displacement / force",
                         f"{_pct(t3['displacement'][2])} / {_pct(t3['force'][2])}", "", ""))
        for row in d["modes_rows"]:
            bundled.append(F(f"{row[0]}; identified on {row[1]}; H(q) calibration {row[2]}: displacement / force",
                             f"{_pct(row[3])} / {_pct(row[4])}", "", ""))
    return {"speed": speed + pipe, "bundled": bundled}


def _pct(cell: str) -> str:
    m = re.search(r"[-0-9.]+", cell)
    return f"{float(m.group()):.2f} %" if m else cell


def _device_table_figures(src: str, what: str, command: str, date: str,
                          superseded: dict[tuple[str, str], str] | None = None, history: bool = False) -> list[Fig]:
    """One row per family and preset of a ``selfsense devices bench`` table (``cross_device.csv``): median (p90)
    displacement / force against the targets (clean 5 / 8 %, drift 8 / 12 %); ``what`` names the benchmark case.
    ``superseded`` maps (family, preset) to a note saying which later row replaces that row (its figures stay)."""
    out = []
    for r in sorted(csv.DictReader((ROOT / src).open()), key=lambda r: (r["preset"], r["family"])):
        tgt = (5, 8) if r["preset"] == "clean" else (8, 12)
        dm, fm = float(r["displacement_median_pct"]), float(r["force_median_pct"])
        note = (superseded or {}).get((r["family"], r["preset"]))
        out.append(Fig(f"{FAMILY.get(r['family'], r['family'])}, {r['preset']} preset, {what} ({r['n_devices']} "
                       f"devices, {r['n_failed']} failed): median (p90) displacement / force"
                       + (f"; **superseded**: {note}" if note else ""),
                       f"{dm:.2f} ({float(r['displacement_p90_pct']):.2f}) / {fm:.2f} "
                       f"({float(r['force_p90_pct']):.2f}) %", f"{tgt[0]} / {tgt[1]} %",
                       _met(dm <= tgt[0] and fm <= tgt[1]) + (" (superseded)" if note else ""), src, command, date,
                       history=history))
    return out


def _if_made(folder: str, rows: Callable[[], list[Fig]]) -> list[Fig]:
    """``rows()``, the figures of one benchmark folder, where that benchmark was run (its ``cross_device.csv`` is
    there), else none: a record folder that a checkout lacks leaves its rows out instead of failing the table."""
    return rows() if (ROOT / folder / "cross_device.csv").exists() else []


def _worst_best_fig(src: str, what: str, command: str, date: str, history: bool = False) -> Fig:
    """The worst / best family ratio of the medians of a ``selfsense devices bench`` table, per preset and measurement
    (issue target: <= 2)."""
    rows = list(csv.DictReader((ROOT / src).open()))
    ratios = {}
    for pre in ("clean", "drift"):
        for m in ("displacement", "force"):
            v = [float(r[f"{m}_median_pct"]) for r in rows if r["preset"] == pre]
            ratios[(pre, m)] = max(v) / min(v)
    val = "; ".join(f"{pre} {ratios[(pre, 'displacement')]:.2f} / {ratios[(pre, 'force')]:.2f}"
                    for pre in ("clean", "drift"))
    return Fig(f"{what}: worst / best family of the median displacement / force", val, "<= 2",
               _met(all(x <= 2 for x in ratios.values())), src, command, date, history=history)


WHOLE_HOLD = "benchmarks/cross_device/whole_device/thesis_hold_rows"
WHOLE_DUHEM = "benchmarks/cross_device/whole_device/thesis_hold_rows_duhem_linear"
WHOLE_RELAY = "benchmarks/cross_device/whole_device/thesis_relay_fix"
WHOLE_ADC18 = "benchmarks/cross_device/whole_device/thesis_adc18"
WHOLE_CRES = "benchmarks/cross_device/whole_device/thesis_charge_resolution"
WHOLE_FM = "benchmarks/cross_device/whole_device/thesis_fold_majority"
WHOLE_HG = "benchmarks/cross_device/whole_device/thesis_holds_g"
WHOLE_QZ = "benchmarks/cross_device/whole_device/thesis_quantiser"
WHOLE_QZB = "benchmarks/cross_device/whole_device/thesis_quantiser_bound"
WHOLE_LAG = "benchmarks/cross_device/whole_device/lag_fresh70"
WHOLE_LAG_OFF = "benchmarks/cross_device/whole_device/lag_off_fresh70"
WHOLE_LAG_GATE = "benchmarks/cross_device/whole_device/lag_gate_fresh70"
WHOLE_DUHEM_BEFORE72 = "benchmarks/cross_device/whole_device/duhem_before_fresh72"
WHOLE_DUHEM_JOINT72 = "benchmarks/cross_device/whole_device/duhem_joint_fresh72"
WHOLE_DUHEM_JOINT70 = "benchmarks/cross_device/whole_device/duhem_joint_fresh70"
WHOLE_JOINT_BEFORE74 = "benchmarks/cross_device/whole_device/joint_before_fresh74"
WHOLE_JOINT_CAND74 = "benchmarks/cross_device/whole_device/joint_candidate_fresh74"
WHOLE_CURRENT76 = "benchmarks/cross_device/whole_device/current_fresh76"
WHOLE_QLASER76 = "benchmarks/cross_device/whole_device/quantiser_laser_fresh76"
WHOLE_QBEFORE79 = "benchmarks/cross_device/whole_device/quantiser_before_fresh79"
WHOLE_QLASER79 = "benchmarks/cross_device/whole_device/quantiser_laser_fresh79"
WHOLE_ENVB82 = "benchmarks/cross_device/whole_device/envelope_before_fresh82"
WHOLE_ENVA82 = "benchmarks/cross_device/whole_device/envelope_after_fresh82"
WHOLE_CUR85 = "benchmarks/cross_device/whole_device/current_fresh85"
WHOLE_CUR88 = "benchmarks/cross_device/whole_device/current_fresh88"
WHOLE_RSIGN88 = "benchmarks/cross_device/whole_device/rest_sign_fresh88"
WHOLE_REV91 = "benchmarks/cross_device/whole_device/reversible_fresh91"
WHOLE_REVB91 = "benchmarks/cross_device/whole_device/before_reversible_fresh91"
WHOLE_REV94 = "benchmarks/cross_device/whole_device/reversible_fresh94"
WHOLE_WOOD91 = "benchmarks/cross_device/whole_device/without_offset_drift_fresh91"
WHOLE_WOLEAK91 = "benchmarks/cross_device/whole_device/without_leakage_fresh91"
WHOLE_WOCREEP91 = "benchmarks/cross_device/whole_device/without_creep_fresh91"
WHOLE_ADC18_91 = "benchmarks/cross_device/whole_device/adc18_fresh91"
WHOLE_ADC18_D91 = "benchmarks/cross_device/whole_device/adc18_drift_fresh91"
WHOLE_WEAK94 = "benchmarks/cross_device/whole_device/weak_reference_fresh94"
#: the current code on whole-device seeds nothing had been scored on (first contact): folder -> key of COMMANDS, DATES
WHOLE_FRESH97 = {"benchmarks/cross_device/whole_device/current_fresh97": "whole_device_current_fresh97",
                 "benchmarks/cross_device/whole_device/current_drift_fresh97": "whole_device_current_drift_fresh97"}
#: the same on seeds 100-101 (the code of rig.yaml amplifier_current_limit_a and the drive coverage; estimator unchanged)
WHOLE_FRESH100 = {"benchmarks/cross_device/whole_device/current_fresh100": "whole_device_current_fresh100",
                  "benchmarks/cross_device/whole_device/current_drift_fresh100": "whole_device_current_drift_fresh100"}
#: the --jobs each preset's run into WHOLE_DUHEM was made with (the records do not depend on it)
WHOLE_DUHEM_JOBS = {"clean": 1, "drift": 2}


def _duhem_linear_rescore() -> dict[tuple[str, str], dict]:
    """The devices rescored after the Duhem model got its linear term (``WHOLE_DUHEM``/records) against the records of
    the same devices (same family, preset, seed) in ``WHOLE_HOLD``/records, per (family, preset): the new and the old
    records, and how many record files differ byte for byte."""
    groups: dict[tuple[str, str], dict] = {}
    for p in sorted((ROOT / WHOLE_DUHEM / "records").glob("*.json")):
        new = json.loads(p.read_text())
        old_p = ROOT / WHOLE_HOLD / "records" / p.name
        if not old_p.exists():
            raise SystemExit(f"benchmarks/figures.py: {WHOLE_DUHEM}/records/{p.name} has no record of the same device "
                             f"in {WHOLE_HOLD}/records")
        g = groups.setdefault((new["family"], new["preset"]), {"new": [], "old": [], "changed": 0, "seeds": []})
        g["new"].append(new)
        g["old"].append(json.loads(old_p.read_text()))
        g["seeds"].append(int(new["seed"]))
        g["changed"] += p.read_bytes() != old_p.read_bytes()
    return groups


def _seed_span(seeds: list[int]) -> str:
    s = sorted(seeds)
    return f"{s[0]}-{s[-1]}" if s == list(range(s[0], s[-1] + 1)) else ",".join(map(str, s))


def duhem_linear_figures(groups: dict[tuple[str, str], dict]) -> list[Fig]:
    """One row per family and preset of the rescore after the Duhem model's linear term, computed from the committed
    records with the bench's own aggregation (``selfsense.devices.aggregate``), with the same devices' score before
    when a record changed, or the statement that every record is bit-identical."""
    from selfsense.devices import aggregate

    out = []
    for (fam, pre), g in sorted(groups.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        new, old = aggregate(g["new"]).iloc[0], aggregate(g["old"]).iloc[0]
        # the bench's own table in that folder must say the same (it is written by the same aggregation)
        for r in csv.DictReader((ROOT / WHOLE_DUHEM / "cross_device.csv").open()):
            if (r["family"], r["preset"]) == (fam, pre) and any(
                    f"{float(r[k]):.2f}" != f"{new[k]:.2f}" or int(r["n_devices"]) != len(g["new"])
                    for k in ("displacement_median_pct", "displacement_p90_pct", "force_median_pct", "force_p90_pct")):
                raise SystemExit(f"benchmarks/figures.py: {WHOLE_DUHEM}/cross_device.csv disagrees with its records "
                                 f"for {fam} {pre}")
        n, n_hold = len(g["new"]), sum(1 for _ in (ROOT / WHOLE_HOLD / "records").glob(f"{fam}_{pre}_*.json"))
        tgt = (5, 8) if pre == "clean" else (8, 12)
        dm, fm = new["displacement_median_pct"], new["force_median_pct"]
        if g["changed"]:
            then = (f"{g['changed']} of the {n} device records changed; the same {n} devices before: "
                    f"{old['displacement_median_pct']:.2f} ({old['displacement_p90_pct']:.2f}) / "
                    f"{old['force_median_pct']:.2f} ({old['force_p90_pct']:.2f}) %")
        else:
            then = (f"all {n} device records bit-identical to those of the same seeds ({_seed_span(g['seeds'])}) in "
                    f"the row with the hold rows" + (f", a subset of its {n_hold} devices; that row stands"
                                                    if n_hold > n else "; that row stands"))
        # one bench run per number of devices (seeds 0..n-1), over the families rescored with that many
        if sorted(g["seeds"]) != list(range(n)):
            raise SystemExit(f"benchmarks/figures.py: {WHOLE_DUHEM}: {fam} {pre} has seeds {sorted(g['seeds'])}, "
                             f"not 0-{n - 1}: {COMMANDS['whole_device_duhem_linear']} does not describe them")
        cmd = COMMANDS["whole_device_duhem_linear"].format(
            n=n, preset=pre, jobs=WHOLE_DUHEM_JOBS[pre],
            families=",".join(sorted({f for (f, p), h in groups.items() if p == pre and len(h["new"]) == n})))
        out.append(Fig(f"{FAMILY.get(fam, fam)}, whole-device randomisation, thesis calibration, with the hold rows, "
                       f"with the Duhem linear term (commit of 2026-11-26), {pre} preset, {n} devices "
                       f"({int(new['n_failed'])} failed): median (p90) displacement / force; {then}",
                       f"{dm:.2f} ({new['displacement_p90_pct']:.2f}) / {fm:.2f} ({new['force_p90_pct']:.2f}) %",
                       f"{tgt[0]} / {tgt[1]} %", _met(dm <= tgt[0] and fm <= tgt[1]), f"{WHOLE_DUHEM}/records", cmd,
                       DATES["whole_device_duhem_linear"], history=True))
    return out


def cross_device_figures() -> list[Fig]:
    groups = _duhem_linear_rescore()
    superseded = {}
    for (fam, pre), g in groups.items():
        if g["changed"]:
            hold_seeds = [int(q.stem.rsplit("_", 1)[1])
                          for q in (ROOT / WHOLE_HOLD / "records").glob(f"{fam}_{pre}_*.json")]
            rest = sorted(set(hold_seeds) - set(g["seeds"]))
            superseded[(fam, pre)] = (
                f"rescored with the Duhem linear term on seeds {_seed_span(g['seeds'])}, whose records changed on "
                f"{g['changed']} of {len(g['new'])} devices (row with the Duhem linear term below)"
                + (f"; seeds {_seed_span(rest)} not rescored" if rest else ""))
    return (_device_table_figures("benchmarks/cross_device/cross_device.csv", "three-trial calibration",
                                  COMMANDS["cross_device"], DATES["cross_device"])
            # the fifth family's first contact on the thesis protocol, scored once before any estimator change for it
            # (its three-trial first contact is the same 20 devices as its rows of the main table)
            + _device_table_figures("benchmarks/cross_device/first_contact_rate_kp/thesis/cross_device.csv",
                                    "thesis calibration (two sines), first contact",
                                    COMMANDS["first_contact_rate_kp"].format(protocol="thesis"),
                                    DATES["first_contact_rate_kp"])
            # the whole-device randomisation on the thesis protocol, five families: its first contact
            + _device_table_figures("benchmarks/cross_device/whole_device/thesis/cross_device.csv",
                                    "whole-device randomisation, thesis calibration, first contact",
                                    COMMANDS["whole_device"], DATES["whole_device"])
            + [_worst_best_fig("benchmarks/cross_device/whole_device/thesis/cross_device.csv",
                               "whole-device randomisation, thesis calibration, first contact", COMMANDS["whole_device"],
                               DATES["whole_device"])]
            # the same 100 devices scored again after the hold rows of the H(q) fit (docs/method.md 6b'); a family's
            # row is superseded where the Duhem linear term changed any of its rescored devices' records
            + _device_table_figures(f"{WHOLE_HOLD}/cross_device.csv",
                                    "whole-device randomisation, thesis calibration, with the hold rows",
                                    COMMANDS["whole_device_hold_rows"], DATES["whole_device_hold_rows"],
                                    superseded=superseded, history=True)
            # the clean devices rescored after the Duhem model got its own linear term
            + duhem_linear_figures(groups)
            # seeds 0-4 of all five families and both presets with the current code: the simulator's relay fix
            # (docs/method.md) changes the records of the devices whose relay segment carried the residual current
            + _if_made(WHOLE_RELAY, lambda: _device_table_figures(f"{WHOLE_RELAY}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, after the simulator relay fix "
                                     "and the holds' bound on the calibration leakage, seeds 0-4",
                                     COMMANDS["whole_device_relay_fix"], DATES["whole_device_relay_fix"], history=True))
            # the same seeds with the current code: the hold evidence gated by the charge resolution (1 of 50 records
            # changed); seeds 5-9 added with the same code (first contact, 10 devices per family and preset)
            + _if_made(WHOLE_CRES, lambda: _device_table_figures(f"{WHOLE_CRES}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, hold evidence gated by the "
                                     "charge resolution (before the leakage fold majority), seeds 0-9 (5-9 scored "
                                     "once, first contact)",
                                     COMMANDS["whole_device_charge_resolution"],
                                     DATES["whole_device_charge_resolution"], history=True))
            # the same 100 devices with the leakage fold majority and the selected-form check
            + _if_made(WHOLE_FM, lambda: _device_table_figures(f"{WHOLE_FM}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, leakage fold majority and "
                                     "selected-form check (before the holds' g was exempt from it), seeds 0-9",
                                     COMMANDS["whole_device_fold_majority"], DATES["whole_device_fold_majority"],
                                     history=True))
            # the same 100 devices with the newest code scored on them (default configuration): a g the holds
            # measure is not re-checked by the selected form; not rescored after the leakage corroboration rule
            # (2026-11-28, docs/method.md 6c), which changes the devices where the calibration rows and the holds agree
            + _if_made(WHOLE_HG, lambda: _device_table_figures(f"{WHOLE_HG}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, the holds' leakage exempt from "
                                     "the selected-form check (before the leakage corroboration rule), seeds 0-9",
                                     COMMANDS["whole_device_holds_g"], DATES["whole_device_holds_g"])
               + [_worst_best_fig(f"{WHOLE_HG}/cross_device.csv", "whole-device randomisation, thesis calibration, "
                                  "before the leakage corroboration rule, five families, 10 devices each",
                                  COMMANDS["whole_device_holds_g"], DATES["whole_device_holds_g"])])
            # the same 100 devices with the quantiser member switched on (config quantiser: auto, not the default;
            # docs/method.md 1b'): a measured alternative, not the score of the default configuration
            + _if_made(WHOLE_QZ, lambda: _device_table_figures(f"{WHOLE_QZ}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, with the quantiser member "
                                     "switched on (config quantiser: auto, not the default), seeds 0-9",
                                     COMMANDS["whole_device_quantiser"], DATES["whole_device_quantiser"], history=True)
               + [_worst_best_fig(f"{WHOLE_QZ}/cross_device.csv", "whole-device randomisation, thesis calibration, "
                                  "with the quantiser member switched on (not the default), five families, 10 devices "
                                  "each", COMMANDS["whole_device_quantiser"], DATES["whole_device_quantiser"],
                                  history=True)])
            # ... and with its bound gate (docs/method.md 1b'): still switched on by config only
            + _if_made(WHOLE_QZB, lambda: _device_table_figures(f"{WHOLE_QZB}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, with the quantiser member and "
                                     "its bound gate switched on (config quantiser: auto, not the default), seeds 0-9",
                                     COMMANDS["whole_device_quantiser_bound"], DATES["whole_device_quantiser_bound"],
                                     history=True)
               + [_worst_best_fig(f"{WHOLE_QZB}/cross_device.csv", "whole-device randomisation, thesis calibration, "
                                  "with the quantiser member and its bound gate switched on (not the default), five "
                                  "families, 10 devices each", COMMANDS["whole_device_quantiser_bound"],
                                  DATES["whole_device_quantiser_bound"], history=True)])
            # the voltage link's lag member: its first contact on fresh seeds 70-71 (current code), and the same devices
            # with the member forced off
            + _if_made(WHOLE_LAG, lambda: _device_table_figures(f"{WHOLE_LAG}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, fresh seeds 70-71, the amplifier "
                                     "lag member (its first contact, before its separability gate)",
                                     COMMANDS["whole_device_lag_fresh70"], DATES["whole_device_lag_fresh70"])
               + _device_table_figures(f"{WHOLE_LAG_GATE}/cross_device.csv",
                                       "whole-device randomisation, thesis calibration, seeds 70-71 (seen once), the "
                                       "amplifier lag member with its separability gate",
                                       COMMANDS["whole_device_lag_gate_fresh70"], DATES["whole_device_lag_gate_fresh70"])
               + _device_table_figures(f"{WHOLE_LAG_OFF}/cross_device.csv",
                                       "whole-device randomisation, thesis calibration, fresh seeds 70-71, the amplifier "
                                       "lag member forced off", COMMANDS["whole_device_lag_off_fresh70"],
                                       DATES["whole_device_lag_off_fresh70"], history=True))
            # a rejected change, the Duhem map's joint hold search (docs/method.md 6b'): its first contact on fresh seeds
            # 72-73 with the current code beside it, and on seeds 70-71; not in the current code
            + _if_made(WHOLE_DUHEM_JOINT72, lambda: _device_table_figures(f"{WHOLE_DUHEM_JOINT72}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, fresh seeds 72-73, the Duhem "
                                     "map's joint hold search (rejected, not in the current code)",
                                     COMMANDS["whole_device_duhem_joint_fresh72"],
                                     DATES["whole_device_duhem_joint_fresh72"], history=True))
            + _if_made(WHOLE_DUHEM_BEFORE72, lambda: _device_table_figures(f"{WHOLE_DUHEM_BEFORE72}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, fresh seeds 72-73 (before the "
                                     "joint hold candidate)",
                                     COMMANDS["whole_device_duhem_before_fresh72"],
                                     DATES["whole_device_duhem_before_fresh72"], history=True))
            + _if_made(WHOLE_DUHEM_JOINT70, lambda: _device_table_figures(f"{WHOLE_DUHEM_JOINT70}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, seeds 70-71, the Duhem map's "
                                     "joint hold search (rejected, not in the current code)",
                                     COMMANDS["whole_device_duhem_joint_fresh70"],
                                     DATES["whole_device_duhem_joint_fresh70"], history=True))
            # the joint hold search as a candidate of the selection (docs/method.md 6b'): its first contact on fresh
            # seeds 74-75, the code before it on the same devices beside it
            + _if_made(WHOLE_JOINT_CAND74, lambda: _device_table_figures(f"{WHOLE_JOINT_BEFORE74}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, fresh seeds 74-75, before the "
                                     "joint hold candidate", COMMANDS["whole_device_joint_before_fresh74"],
                                     DATES["whole_device_joint_before_fresh74"], history=True)
               + _device_table_figures(f"{WHOLE_JOINT_CAND74}/cross_device.csv",
                                       "whole-device randomisation, thesis calibration, fresh seeds 74-75, the joint "
                                       "hold candidate (its first contact)",
                                       COMMANDS["whole_device_joint_candidate_fresh74"],
                                       DATES["whole_device_joint_candidate_fresh74"]))
            # the quantiser member identified on the free-tip laser and on by default (docs/method.md 1b'): the code
            # before it on fresh seeds 76-78 (first contact of that code) and with it (seen once); then its first
            # contact on fresh seeds 79-81 with the code before it on the same devices beside it
            + _if_made(WHOLE_QLASER76, lambda: _device_table_figures(f"{WHOLE_CURRENT76}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, fresh seeds 76-78, the code "
                                     "before the quantiser member on the free-tip laser",
                                     COMMANDS["whole_device_current_fresh76"], DATES["whole_device_current_fresh76"],
                                     history=True)
               + _device_table_figures(f"{WHOLE_QLASER76}/cross_device.csv",
                                       "whole-device randomisation, thesis calibration, seeds 76-78 (seen once), the "
                                       "quantiser member on the free-tip laser",
                                       COMMANDS["whole_device_quantiser_laser_fresh76"],
                                       DATES["whole_device_quantiser_laser_fresh76"], history=True))
            + _if_made(WHOLE_QLASER79, lambda: _device_table_figures(f"{WHOLE_QBEFORE79}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, fresh seeds 79-81, the code "
                                     "before the quantiser member on the free-tip laser",
                                     COMMANDS["whole_device_quantiser_before_fresh79"],
                                     DATES["whole_device_quantiser_before_fresh79"], history=True)
               + _device_table_figures(f"{WHOLE_QLASER79}/cross_device.csv",
                                       "whole-device randomisation, thesis calibration, fresh seeds 79-81, the quantiser "
                                       "member on the free-tip laser (its first contact)",
                                       COMMANDS["whole_device_quantiser_laser_fresh79"],
                                       DATES["whole_device_quantiser_laser_fresh79"], history=True)
               + [_worst_best_fig(f"{WHOLE_QLASER79}/cross_device.csv", "whole-device randomisation, thesis "
                                  "calibration, fresh seeds 79-81, the quantiser member on the free-tip laser (first "
                                  "contact), five families, 3 devices each",
                                  COMMANDS["whole_device_quantiser_laser_fresh79"],
                                  DATES["whole_device_quantiser_laser_fresh79"], history=True)])
            # the H(q) selection's major-loop check and the holds' upper bound on leakage (docs/method.md 6b, 6c):
            # fresh seeds 82-84 scored with the code before them (first contact of that code), then with them
            + _if_made(WHOLE_ENVA82, lambda: _device_table_figures(f"{WHOLE_ENVB82}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, fresh seeds 82-84, the code "
                                     "before the major-loop check and the holds' leakage bound",
                                     COMMANDS["whole_device_envelope_before_fresh82"],
                                     DATES["whole_device_envelope_before_fresh82"], history=True)
               + _device_table_figures(f"{WHOLE_ENVA82}/cross_device.csv",
                                       "whole-device randomisation, thesis calibration, fresh seeds 82-84, the major-loop "
                                       "check and the holds' leakage bound (their first contact; the seed-85 rows are "
                                       "the current code)",
                                       COMMANDS["whole_device_envelope_after_fresh82"],
                                       DATES["whole_device_envelope_after_fresh82"], history=True)
               + [_worst_best_fig(f"{WHOLE_ENVA82}/cross_device.csv", "whole-device randomisation, thesis "
                                  "calibration, fresh seeds 82-84, the major-loop check and the holds' leakage bound "
                                  "(first contact), five families, 3 devices each",
                                  COMMANDS["whole_device_envelope_after_fresh82"],
                                  DATES["whole_device_envelope_after_fresh82"], history=True)])
            # the code of f64a0a5 on fresh seeds 85-87: its first contact, scored once as it came
            + _if_made(WHOLE_CUR85, lambda: _device_table_figures(f"{WHOLE_CUR85}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, fresh seeds 85-87 (first contact "
                                     "of the code before the Preisach reversible part)",
                                     COMMANDS["whole_device_current_fresh85"], DATES["whole_device_current_fresh85"],
                                     history=True)
               + [_worst_best_fig(f"{WHOLE_CUR85}/cross_device.csv", "whole-device randomisation, thesis "
                                  "calibration, fresh seeds 85-87 (first contact of the code before the Preisach "
                                  "reversible part), five families, 3 devices each",
                                  COMMANDS["whole_device_current_fresh85"], DATES["whole_device_current_fresh85"],
                                  history=True)])
            # the same code on fresh seeds 88-90: its second first contact; then the rest segments' sign test of the
            # offset drift (a rule not in the code, docs/cross_device.md) on the same devices, its first contact
            + _if_made(WHOLE_CUR88, lambda: _device_table_figures(f"{WHOLE_CUR88}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, fresh seeds 88-90 (first contact "
                                     "of the code before the Preisach reversible part)",
                                     COMMANDS["whole_device_current_fresh88"], DATES["whole_device_current_fresh88"],
                                     history=True)
               + [_worst_best_fig(f"{WHOLE_CUR88}/cross_device.csv", "whole-device randomisation, thesis "
                                  "calibration, fresh seeds 88-90 (first contact of the code before the Preisach "
                                  "reversible part), five families, 3 devices each",
                                  COMMANDS["whole_device_current_fresh88"], DATES["whole_device_current_fresh88"],
                                  history=True)])
            # the current code, with the Preisach reversible part (docs/method.md 6b), on fresh seeds 91-93: its
            # first contact, scored once as it came; beside it the code before it on the same devices
            + _if_made(WHOLE_REVB91, lambda: _device_table_figures(f"{WHOLE_REVB91}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, fresh seeds 91-93, the code "
                                     "before the Preisach reversible part",
                                     COMMANDS["whole_device_before_reversible_fresh91"],
                                     DATES["whole_device_before_reversible_fresh91"], history=True))
            + _if_made(WHOLE_REV91, lambda: _device_table_figures(f"{WHOLE_REV91}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, fresh seeds 91-93 (first contact "
                                     "of the current code, with the Preisach reversible part)",
                                     COMMANDS["whole_device_reversible_fresh91"],
                                     DATES["whole_device_reversible_fresh91"])
               + [_worst_best_fig(f"{WHOLE_REV91}/cross_device.csv", "whole-device randomisation, thesis "
                                  "calibration, fresh seeds 91-93 (first contact of the current code, with the "
                                  "Preisach reversible part), five families, 3 devices each",
                                  COMMANDS["whole_device_reversible_fresh91"],
                                  DATES["whole_device_reversible_fresh91"])])
            # the same code on fresh seeds 94-96: its second first contact
            + _if_made(WHOLE_REV94, lambda: _device_table_figures(f"{WHOLE_REV94}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, fresh seeds 94-96 (first contact "
                                     "of the current code, its second)",
                                     COMMANDS["whole_device_reversible_fresh94"],
                                     DATES["whole_device_reversible_fresh94"])
               + [_worst_best_fig(f"{WHOLE_REV94}/cross_device.csv", "whole-device randomisation, thesis "
                                  "calibration, fresh seeds 94-96 (first contact of the current code, its second), "
                                  "five families, 3 devices each",
                                  COMMANDS["whole_device_reversible_fresh94"],
                                  DATES["whole_device_reversible_fresh94"])])
            # the device that failed the contract at 19.1x its noise, scored once the weak reference is a warning
            + _if_made(WHOLE_WEAK94, lambda: _device_table_figures(f"{WHOLE_WEAK94}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, rate-dependent KP seed 96 (the "
                                     "device of seeds 94-96 that failed the data contract, scored once a weak "
                                     "reference is a warning)", COMMANDS["whole_device_weak_reference_fresh94"],
                                     DATES["whole_device_weak_reference_fresh94"]))
            # effect-free twins of the drift preset: what one effect costs (a diagnosis, not a score of the benchmark)
            + _if_made(WHOLE_WOOD91, lambda: _device_table_figures(f"{WHOLE_WOOD91}/cross_device.csv",
                                     "the drift devices of seeds 91-93 without their offset drift (effect-free twins; "
                                     "diagnosis: what the offset drift costs)",
                                     COMMANDS["whole_device_without_offset_drift_fresh91"],
                                     DATES["whole_device_without_offset_drift_fresh91"]))
            + _if_made(WHOLE_WOLEAK91, lambda: _device_table_figures(f"{WHOLE_WOLEAK91}/cross_device.csv",
                                     "the drift devices of seeds 91-93 without their leakage (effect-free twins; "
                                     "diagnosis: what the leakage costs)",
                                     COMMANDS["whole_device_without_leakage_fresh91"],
                                     DATES["whole_device_without_leakage_fresh91"]))
            + _if_made(WHOLE_WOCREEP91, lambda: _device_table_figures(f"{WHOLE_WOCREEP91}/cross_device.csv",
                                     "the drift devices of seeds 91-93 without their mechanical creep (effect-free "
                                     "twins; diagnosis: what the creep costs)",
                                     COMMANDS["whole_device_without_creep_fresh91"],
                                     DATES["whole_device_without_creep_fresh91"]))
            + _if_made(WHOLE_RSIGN88, lambda: _device_table_figures(f"{WHOLE_RSIGN88}/cross_device.csv",
                                     "whole-device randomisation, thesis calibration, fresh seeds 88-90, the offset "
                                     "drift adopted from the rests' sign test (its first contact; rejected, not in the "
                                     "code)",
                                     COMMANDS["whole_device_rest_sign_fresh88"],
                                     DATES["whole_device_rest_sign_fresh88"], history=True))
            # the same devices, drives and noise with an 18-bit ADC: what the drawn 12-18-bit ADC costs (the
            # charge resolution, docs/method.md 1b); a diagnosis of the rows above, not a score of the benchmark
            + _if_made(WHOLE_ADC18, lambda: _device_table_figures(f"{WHOLE_ADC18}/cross_device.csv",
                                     "the same devices with an 18-bit ADC (diagnosis: what the drawn ADC costs), "
                                     "seeds 0-4", COMMANDS["whole_device_adc18"], DATES["whole_device_adc18"]))
            + _if_made(WHOLE_ADC18_91, lambda: _device_table_figures(f"{WHOLE_ADC18_91}/cross_device.csv",
                                     "the clean devices of seeds 91-96 with an 18-bit ADC (diagnosis: what the drawn "
                                     "ADC costs the current code)", COMMANDS["whole_device_adc18_fresh91"],
                                     DATES["whole_device_adc18_fresh91"]))
            + _if_made(WHOLE_ADC18_D91, lambda: _device_table_figures(f"{WHOLE_ADC18_D91}/cross_device.csv",
                                     "the drift devices of seeds 91-96 with an 18-bit ADC (diagnosis: what the drawn "
                                     "ADC costs the current code)", COMMANDS["whole_device_adc18_drift_fresh91"],
                                     DATES["whole_device_adc18_drift_fresh91"]))
            + [f for src, key in WHOLE_FRESH97.items() if (ROOT / src / "cross_device.csv").exists()
               for f in _device_table_figures(f"{src}/cross_device.csv", "whole-device randomisation, thesis "
                                              "calibration, fresh seeds 97-99 (current code, first contact)",
                                              COMMANDS[key], DATES[key])]
            + [f for src, key in WHOLE_FRESH100.items() if (ROOT / src / "cross_device.csv").exists()
               for f in _device_table_figures(f"{src}/cross_device.csv", "whole-device randomisation, thesis "
                                              "calibration, fresh seeds 100-101 (current code, first contact"
                                              + ("; rate-dependent KP refused by the data contract then, scored "
                                                 "after its current-limit fix)" if "drift" not in key else ")"),
                                              COMMANDS[key], DATES[key])])


ERROR_CAUSES = {"fresh seeds 42-43 (first contact of the measure)":
                ("benchmarks/cross_device/whole_device/fold_starts_fresh42/error_causes.md", "error_causes_fresh42"),
                "seeds 0-1 (current code)":
                ("benchmarks/cross_device/whole_device/current_seeds0/error_causes.md", "error_causes_seeds0")}


def error_cause_figures() -> list[Fig]:
    """How well the calibration's own measures (the H(q) error cost, docs/method.md 6g, and the charge resolution,
    1b) rank the devices' Table 3 on the whole device: a diagnosis of the misses, not a score."""
    out = []
    for what, (src, key) in ERROR_CAUSES.items():
        if not (ROOT / src).exists():
            continue
        text = (ROOT / src).read_text()
        n = re.search(r"^(\d+) devices\.", text, re.M).group(1)
        cells = []
        for meas in ("H(q) error through A2 / B22", "the larger of the two"):
            rho = []
            for m in ("displacement", "force"):
                g = re.search(rf"^\| {m} \| {re.escape(meas)} \| ([-0-9.]+) \| ([0-9.e+-]+) \|", text, re.M)
                rho.append(f"{g.group(1)} (p {float(g.group(2)):.0e})")
            cells.append(" / ".join(rho))
        out.append(Fig(f"whole-device randomisation, thesis calibration, {what}, {n} devices: Spearman rank correlation "
                       f"of Table 3 (displacement / force) with the calibration-time H(q) error through A2 / B22; with "
                       f"the larger of it and the charge resolution",
                       f"{cells[0]}; {cells[1]}", "", "measured", src, COMMANDS[key], DATES[key]))
    return out


def hold_rows_figures() -> list[Fig]:
    """The hold rows of the H(q) fit against none, same devices and data (benchmarks/hold_rows.py)."""
    src = "benchmarks/hold_rows/records.jsonl"
    recs = [json.loads(x) for x in (ROOT / src).read_text().splitlines() if x.strip()]
    out = []
    for hold in sorted({r["hold_s"] for r in recs}):
        rs = [r for r in recs if r["hold_s"] == hold]
        med = {m: (statistics.median(r[m]["displacement_pct"] for r in rs),
                   statistics.median(r[m]["force_pct"] for r in rs)) for m in ("off", "auto")}
        better = sum(r["auto"]["displacement_pct"] < 0.9 * r["off"]["displacement_pct"] for r in rs)
        worse = sum(r["auto"]["displacement_pct"] > 1.1 * r["off"]["displacement_pct"] for r in rs)
        out.append(Fig(f"hold rows of the H(q) fit, thesis protocol, holds of {hold:g} s ({len(rs)} devices, five "
                       "families, clean and drift): median displacement / force without -> with; devices better / "
                       "worse by > 10 %", f"{med['off'][0]:.2f} / {med['off'][1]:.2f} % -> {med['auto'][0]:.2f} / "
                       f"{med['auto'][1]:.2f} %; {better} / {worse}", "", "measured", src, COMMANDS["hold_rows"],
                       DATES["hold_rows"]))
    return out


def stage_chain_figures() -> list[Fig]:
    """Thesis protocol, clean against drift, per family: the newest scoring of each family on seeds 0-5 (older ones
    are in CHANGELOG.md), and the first contact of the current code on fresh seeds."""
    load = lambda rel: [json.loads(x) for x in (ROOT / rel).read_text().splitlines() if x.strip()]  # noqa: E731
    # oldest first; a family's row comes from the newest source that scored it
    sources = [("benchmarks/stage_chain/thesis/records.jsonl", "", "stage_chain"),
               ("benchmarks/stage_chain/thesis_duhem_linear/records.jsonl", ", with the Duhem linear term",
                "stage_chain_duhem_linear"),
               ("benchmarks/stage_chain/thesis_relay_bound/records.jsonl", ", simulator relay fix and the holds' "
                "bound on the calibration leakage (2026-11-27)", "stage_chain_relay_bound"),
               ("benchmarks/stage_chain/fold_majority/records.jsonl", ", leakage fold majority and selected-form "
                "check", "stage_chain_fold_majority"),
               ("benchmarks/stage_chain/holds_g/records.jsonl", ", the holds' leakage exempt from the selected-form "
                "check", "stage_chain_holds_g"),
               ("benchmarks/stage_chain/corroborated/records.jsonl", ", leakage where the calibration rows and the "
                "holds agree (the code before the leakage-by-selection rule of 2026-12-02)", "stage_chain_corroborated"),
               ("benchmarks/stage_chain/selection_leak/records.jsonl", ", leakage decided again by the H(q) selection "
                "(before the fold starts of the non-convex final fit)", "stage_chain_selection_leak"),
               ("benchmarks/stage_chain/fold_starts/records.jsonl", ", the non-convex final fit also started from its "
                "fold fits (2026-12-02)", "stage_chain_fold_starts"),
               ("benchmarks/stage_chain/current_seeds0_5/records.jsonl", ", the same seeds scored again on 2026-12-04 "
                "(current code)", "stage_chain_current_seeds0_5")]
    # fresh seeds: the code before the fold majority, then the current code (seeds 400-405: its first contact)
    fresh = [("benchmarks/stage_chain/thesis_relay_bound_fresh/records.jsonl", ", first contact on fresh seeds "
              "300-305 (simulator relay fix, holds' bound)", "stage_chain_relay_bound_fresh"),
             ("benchmarks/stage_chain/holds_g_fresh300/records.jsonl", ", seeds 300-305 (seen before), the holds' "
              "leakage exempt from the selected-form check", "stage_chain_holds_g_fresh300"),
             ("benchmarks/stage_chain/thesis_relay_bound_fresh400/records.jsonl", ", fresh seeds 400-405, the code "
              "before the fold majority", "stage_chain_relay_bound_fresh400"),
             ("benchmarks/stage_chain/fold_majority_fresh400/records.jsonl", ", fresh seeds 400-405, leakage fold "
              "majority (its first contact)", "stage_chain_fold_majority_fresh400"),
             ("benchmarks/stage_chain/holds_g_fresh400/records.jsonl", ", seeds 400-405 (seen once), the holds' "
              "leakage exempt from the selected-form check", "stage_chain_holds_g_fresh400"),
             ("benchmarks/stage_chain/corroborated_fresh300/records.jsonl", ", seeds 300-305 (seen before), the code "
              "before the leakage-by-selection rule", "stage_chain_corroborated_fresh300"),
             ("benchmarks/stage_chain/corroborated_fresh400/records.jsonl", ", seeds 400-405 (seen before), the code "
              "before the leakage-by-selection rule", "stage_chain_corroborated_fresh400"),
             ("benchmarks/stage_chain/holds_g_fresh500/records.jsonl", ", fresh seeds 500-505, the code before the "
              "leakage corroboration rule", "stage_chain_holds_g_fresh500"),
             ("benchmarks/stage_chain/corroborated_fresh500/records.jsonl", ", fresh seeds 500-505, leakage where the "
              "calibration rows and the holds agree (its first contact)",
              "stage_chain_corroborated_fresh500"),
             ("benchmarks/stage_chain/selection_leak_fresh500/records.jsonl", ", seeds 500-505 (seen once), leakage "
              "decided again by the H(q) selection", "stage_chain_selection_leak_fresh500"),
             ("benchmarks/stage_chain/before_selection_leak_fresh600/records.jsonl", ", fresh seeds 600-605, the code "
              "before the leakage-by-selection rule", "stage_chain_before_selection_leak_fresh600"),
             ("benchmarks/stage_chain/selection_leak_fresh600/records.jsonl", ", fresh seeds 600-605, leakage decided "
              "again by the H(q) selection (its first contact)", "stage_chain_selection_leak_fresh600"),
             ("benchmarks/stage_chain/before_fold_starts_fresh700/records.jsonl", ", fresh seeds 700-702, the code "
              "before the fold starts of the non-convex final fit", "stage_chain_before_fold_starts_fresh700"),
             ("benchmarks/stage_chain/fold_starts_fresh700/records.jsonl", ", fresh seeds 700-702, the non-convex "
              "final fit also started from its fold fits (its first contact)",
              "stage_chain_fold_starts_fresh700"),
             ("benchmarks/stage_chain/tip_creep_off_fresh800/records.jsonl", ", fresh seeds 800-803, the creep member "
              "forced off", "stage_chain_tip_creep_off_fresh800"),
             ("benchmarks/stage_chain/tip_creep_fresh800/records.jsonl", ", fresh seeds 800-803, the creep member "
              "(its first contact)", "stage_chain_tip_creep_fresh800"),
             ("benchmarks/stage_chain/drift_refit_fresh806/records.jsonl", ", fresh seeds 806-809, the offset drift "
              "beside the creep member decided against the chain calibrated without it (its first contact; current "
              "code)", "stage_chain_drift_refit_fresh806"),
             ("benchmarks/stage_chain/current_fresh900/records.jsonl", ", fresh seeds 900-905, the code of "
              "2026-12-04 (its first contact)", "stage_chain_current_fresh900"),
             ("benchmarks/stage_chain/lag_off_fresh1000/records.jsonl", ", fresh seeds 1000-1002, the amplifier lag "
              "member forced off", "stage_chain_lag_off_fresh1000"),
             ("benchmarks/stage_chain/lag_fresh1000/records.jsonl", ", fresh seeds 1000-1002, the amplifier lag "
              "member (its first contact, before its separability gate)", "stage_chain_lag_fresh1000"),
             ("benchmarks/stage_chain/lag_gate_fresh1000/records.jsonl", ", seeds 1000-1002 (seen once), the amplifier "
              "lag member with its separability gate (current code)", "stage_chain_lag_gate_fresh1000")]
    newest = {}
    for rel, what, key in sources:
        if (ROOT / rel).exists():
            recs = load(rel)
            for fam in {r["family"] for r in recs}:
                newest[fam] = (recs, rel, what, key)

    def row(rs, fam, what, source, key, history=False):
        med = {}
        for p in ("clean", "drift"):
            v = [r for r in rs if r["family"] == fam and r["preset"] == p]
            med[p] = (statistics.median(r["displacement_pct"] for r in v),
                      statistics.median(r["force_pct"] for r in v), len(v))
        rd, rf = med["drift"][0] / med["clean"][0], med["drift"][1] / med["clean"][1]
        ok = rd <= 1.3 and rf <= 1.3 and all(med["drift"][k] <= med["clean"][k] + 2.0 for k in (0, 1))
        return Fig(f"{FAMILY.get(fam, fam)}, thesis protocol (two sine calibration trials, {med['clean'][2]} + "
                   f"{med['drift'][2]} devices){what}: median displacement / force, clean; drift",
                   f"{med['clean'][0]:.2f} / {med['clean'][1]:.2f} %; {med['drift'][0]:.2f} / "
                   f"{med['drift'][1]:.2f} % (drift / clean {rd:.2f}, {rf:.2f})",
                   "drift / clean <= 1.3 and drift <= clean + 2 points", _met(ok), source, COMMANDS[key].format(
                       families=",".join(sorted(f for f, v in newest.items() if v[1] == source))), DATES[key],
                   history=history)

    out = [row(recs, fam, what, rel, key) for fam, (recs, rel, what, key) in sorted(newest.items())]
    # on each fresh seed set: its first contact and the current code; the scorings between them are history
    current = {"stage_chain_relay_bound_fresh", "stage_chain_corroborated_fresh300", "stage_chain_fold_majority_fresh400",
               "stage_chain_corroborated_fresh400", "stage_chain_corroborated_fresh500",
               "stage_chain_selection_leak_fresh600", "stage_chain_selection_leak_fresh500",
               "stage_chain_tip_creep_fresh800", "stage_chain_drift_refit_fresh806", "stage_chain_current_fresh900",
               "stage_chain_lag_fresh1000", "stage_chain_lag_gate_fresh1000"}
    for rel, what, key in fresh:
        if (ROOT / rel).exists():
            recs = load(rel)
            out += [row(recs, fam, what, rel, key, history=key not in current)
                    for fam in sorted({r["family"] for r in recs})]
    return out


def _generations(entries: list[tuple[str, str, str]], marker: str) -> list[tuple[str, str, str]]:
    """The campaigns of one benchmark, oldest first, that exist (``folder/marker``): ``(folder, key, note)``, each
    with its note (what a later campaign changed) only where a later one exists."""
    have = [e for e in entries if (ROOT / e[0] / marker).exists()]
    return [(folder, key, note if i < len(have) - 1 else "") for i, (folder, key, note) in enumerate(have)]


#: tip tiers whose per-effect rows stay in the tables after a newer tier, with what their rows are marked by (the
#: 240-case seed 14142 beside the smaller first tier of the Preisach stand-in; seed 20261202 beside the current code)
TIP_PER_EFFECT = {"gap_tip_14142": "(the PI stand-in) ", "gap_tip_20261202": "(before 2026-12-03) ",
                  "gap_tip_20261213": "(amplifier against the effect-free twin) ",
                  "gap_tip_20261214": "(before the temperature member) ",
                  "gap_tip_20261216": "(before the temperature trend refit held the form) ",
                  "gap_tip_20261217_160": "(before the lag member) ",
                  "gap_tip_20261218": "(before the joint hold candidate) ",
                  "gap_tip_20261219": "(before the widened interval) ",
                  "gap_tip_20261221": "(before the lost-charge member) ",
                  "gap_tip_20261224": "(before the anchors stage) ",
                  "gap_tip_20261227": "(the anchors stage not yet a fallback) ",
                  "gap_tip_20261228": "(the same code, 80 cases of seed 20261228) "}


def _named_enough(row: dict) -> bool:
    """The tip tier's naming target for one effect family (a row of ``cost_table``): >= 90 % of its costly cases named."""
    return row["named"] >= 0.9 * row["costly"]


def gap_figures() -> list[Fig]:
    out = []
    campaigns = [(f"{folder}/scores.json", key, note) for folder, key, note in _generations([
        ("benchmarks/gap_stages", "gap_stages", "; made before the blocked-tip stage and the temperature member's null "
         "floor"),
        ("benchmarks/gap_stages/seed_16180", "gap_stages_16180", "; simulated before the simulator's relay fix (its "
         "residual current gave preload a relay-segment signature, docs/gap.md); the seed-31337 rows are the current "
         "code and simulator"),
        ("benchmarks/gap_stages/seed_31337", "gap_stages_31337", "; made with the earlier stand-in H (a PI of 8 plays), "
         "the seed-20261201 rows are the current code"),
        ("benchmarks/gap_stages/seed_20261201", "gap_stages_20261201", "; made before the wider blocked-stage form of "
         "stress-dependent hysteresis, the seed-20261207 rows are the current code"),
        ("benchmarks/gap_stages/seed_20261207", "gap_stages_20261207", "; the seed-20261223 rows are the current code "
         "(2026-12-06)"),
        ("benchmarks/gap_stages/seed_20261223", "gap_stages_20261223", "; made before the lost-charge form of the "
         "first-loading member, the seed-20261226 rows are the current code (the code before it on that seed: "
         "benchmarks/gap_stages/seed_20261226_before, family top-1 0.849)"),
        ("benchmarks/gap_stages/seed_20261226", "gap_stages_20261226", "; made before the tip-mode member's own null "
         "floor, the seed-5772156 rows are the current code"),
        ("benchmarks/gap_stages/seed_5772156", "gap_stages_5772156", ""),
    ], "scores.json")]
    for src, key, note in campaigns:
        s = json.loads((ROOT / src).read_text())
        F = lambda *a, src=src, key=key: Fig(*a, source=src, command=COMMANDS[key], date=DATES[key])  # noqa: E731
        seed = COMMANDS[key].split("--seed ")[1].split()[0]
        out += [
            F(f"gap diagnostic, blind campaign, seed {seed} ({s['n_cases']} cases): family top-1 "
              f"({s['n_library_present']} cases){note}", f"{s['family_top1']:.3f}", ">= 0.95",
              _met(s["family_top1"] >= 0.95)),
            F(f"gap diagnostic, seed {seed}: member top-1", f"{s['member_top1']:.3f}", ">= 0.90",
              _met(s["member_top1"] >= 0.90)),
            F(f"gap diagnostic, seed {seed}: false alarms on effect-free cases ({s['n_effect_free']})",
              f"{s['false_alarm_rate']:.3f}", "<= 0.05", _met(s["false_alarm_rate"] <= 0.05)),
            F(f"gap diagnostic, seed {seed}: median stage-shrink error ({s['n_shrink']} cases)",
              f"{s['median_shrink_error']:.3f}", "<= 0.15", _met(s["median_shrink_error"] <= 0.15)),
            F(f"gap diagnostic, seed {seed}: open-set cases flagged unexplained ({s['n_open_present']})",
              f"{s['open_set_flagged']:.3f}", ">= 0.70", _met(s["open_set_flagged"] >= 0.70)),
        ]
    import gzip

    from selfsense.gap.blind import cost_table, shrink_by_effect

    seed_90210 = (ROOT / "benchmarks/gap_tip/seed_90210/tip_scores.json").exists()   # rows below refer to it
    tiers = _generations([
        ("benchmarks/gap_tip", "gap_tip",
         "; **superseded**: simulated before the simulator's stress fix, and an effect the estimator already carried "
         "was given a predicted shrink of 0 (an error of 1 by construction); the seed-90210 rows replace it"),
        ("benchmarks/gap_tip/seed_90210", "gap_tip_90210",
         "; made before the absorption member of the charge link (its absorption cases rescored with it below); the "
         "later campaigns are seeds 27182 and 14142"),
        ("benchmarks/gap_tip/seed_27182", "gap_tip_27182",
         "; made before the gap diagnostic's blocked-tip stage (stress-dependent hysteresis) and the temperature "
         "member's null floor; the seed-14142 rows are the newest campaign (2026-11-26, before the simulator's relay "
         "fix and the leakage changes of 2026-11-27)"),
        ("benchmarks/gap_tip/seed_14142", "gap_tip_14142",
         "; made with the earlier stand-in H of the stage diagnosis (a PI of 8 plays), before the simulator's relay fix "
         "and the leakage changes of 2026-11-27; the seed-20261202 rows are the current code"),
        ("benchmarks/gap_tip/seed_20261202", "gap_tip_20261202",
         "; made before the wider blocked-stage form of stress-dependent hysteresis, the stress member's load ridge and "
         "the tip's creep member (2026-12-02 and -03); the seed-20261213 rows are the current code"),
        ("benchmarks/gap_tip/seed_20261213", "gap_tip_20261213",
         "; the amplifier limits' truth from the effect-free twin (rescored with the excitation-matched twin below); "
         "the seed-20261214 rows are the current code"),
        ("benchmarks/gap_tip/seed_20261214", "gap_tip_20261214",
         "; made before the estimator's temperature member (2026-12-05); the seed-20261216 rows are the current code"),
        ("benchmarks/gap_tip/seed_20261216", "gap_tip_20261216",
         "; made before the temperature member's trend refit held the form (its temperature cases may differ slightly); "
         "the seed-20261217 rows are the current code"),
        ("benchmarks/gap_tip/seed_20261217", "gap_tip_20261217",
         "; the first contact of this code, its first 80 cases; the 160-case rows of the same seed follow"),
        ("benchmarks/gap_tip/seed_20261217_160", "gap_tip_20261217_160",
         "; made before the amplifier lag member (2026-12-05); the seed-20261218 rows are the current code"),
        ("benchmarks/gap_tip/seed_20261218", "gap_tip_20261218",
         "; made before the joint hold candidate of the H(q) selection (2026-12-05); the seed-20261219 rows are the "
         "current code"),
        ("benchmarks/gap_tip/seed_20261219", "gap_tip_20261219",
         "; made before the 90 % interval's upper side was widened (2026-12-06: the block bootstrap alone); the "
         "seed-20261221 rows are the current code"),
        ("benchmarks/gap_tip/seed_20261221", "gap_tip_20261221",
         "; made before the lost-charge form of the first-loading member (2026-12-06); the seed-20261224 rows are the "
         "current code"),
        ("benchmarks/gap_tip/seed_20261224", "gap_tip_20261224",
         "; made before the gap diagnostic's stage of the chain's anchors (2026-12-06); the seed-20261228 rows are the "
         "current code"),
        ("benchmarks/gap_tip/seed_20261227", "gap_tip_20261227",
         "; the anchors stage's first contact, before it became a fallback (named wherever its campaign change reached "
         "the rule); the seed-20261228 rows are the current code"),
        ("benchmarks/gap_tip/seed_20261228", "gap_tip_20261228",
         "; the same code's 80 cases of this seed, the seed-20261232 rows are its larger campaign on a fresh seed"),
        ("benchmarks/gap_tip/seed_20261232", "gap_tip_20261232", ""),
    ], "tip_scores.json")
    recs = []
    for folder, key, note in tiers:
        tsrc = f"{folder}/tip_scores.json"
        t = json.loads((ROOT / tsrc).read_text())
        T = lambda *a, key=key, tsrc=tsrc: Fig(*a, source=tsrc, command=COMMANDS[key], date=DATES[key])  # noqa: E731
        seed = COMMANDS[key].split("--seed ")[1].split()[0]
        sup = " (superseded)" if "superseded" in note else ""
        recs = [json.loads(x) for x in gzip.open(ROOT / folder / "tip_cases.jsonl.gz", "rt")]
        costs = cost_table(recs)
        # the target is per effect family: met only where every family with a costly case names >= 90 % of them
        every_family = all(_named_enough(r) for r in costs if r["costly"])
        out.append(T(f"gap diagnostic, tip tier, seed {seed} ({t['n']} single-effect cases with their effect-free "
                     f"twins, a seed not used before): effects that cost >= 3 points of Table 3 and are named{note}",
                     f"{t['n_costly_named']} of {t['n_costly']}", ">= 90 % per effect family",
                     _met(t["n_costly"] > 0 and every_family) + sup))
        out.append(T(f"gap diagnostic, tip tier, seed {seed}: median relative error of the predicted tip shrink "
                     f"({t['n_scored']} cases named right with a real tip consequence); true shrink inside the 90 % "
                     f"interval{note}", f"{t['median_tip_shrink_error']:.2f}; {t['interval_coverage']:.2f}",
                     "<= 0.25; >= 0.80",
                     _met(t["median_tip_shrink_error"] <= 0.25 and t["interval_coverage"] >= 0.8) + sup))
        if note and key not in TIP_PER_EFFECT:
            continue
        how = {r["effect"]: r for r in shrink_by_effect(recs)}
        for r in costs:
            h = how[r["effect"]]
            if not (r["costly"] or h["scored"]):
                continue
            ok_named = _named_enough(r)
            ok_how = not h["scored"] or h["median_error"] <= 0.35
            out.append(T(f"gap diagnostic, tip tier, seed {seed}, {r['effect']}: cases costing >= 3 points named "
                         + (TIP_PER_EFFECT.get(key, "") if note else "")
                         + f"(largest cost {r['max_cost']:.1f} points); cases scored for how far (named, a real tip "
                         "consequence): median relative error of the predicted shrink, truth inside the 90 % "
                         "interval", f"{r['named']} of {r['costly']}; {h['scored']}: "
                         + ("-" if not h["scored"] else f"{h['median_error']:.2f}, {h['inside']} of {h['scored']}"),
                         ">= 90 %; <= 0.35", _met(ok_named and ok_how)))
    msrc = "benchmarks/gap_tip/seed_20261213_matched/tip_scores.json"
    if (ROOT / msrc).exists():
        # the same records, predictions unchanged, the amplifier cases' truth from the excitation-matched twin
        m = json.loads((ROOT / msrc).read_text())
        M = lambda *a: Fig(*a, source=msrc, command=COMMANDS["gap_tip_20261213_matched"],  # noqa: E731
                           date=DATES["gap_tip_20261213_matched"])
        what = ("gap diagnostic, tip tier, seed 20261213 scored again, predictions unchanged, the amplifier limits' "
                "truth from the excitation-matched twin (the voltage the case's amplifier applied)")
        out.append(M(f"{what}: median relative error of the predicted tip shrink ({m['n_scored']} cases named right "
                     "with a real tip consequence); true shrink inside the 90 % interval",
                     f"{m['median_tip_shrink_error']:.3f}; {m['interval_coverage']:.2f}", "<= 0.25; >= 0.80",
                     _met(m["median_tip_shrink_error"] <= 0.25 and m["interval_coverage"] >= 0.8)))
        mrecs = [json.loads(x) for x in gzip.open(ROOT / msrc.replace("tip_scores.json", "tip_cases.jsonl.gz"), "rt")]
        h = next(r for r in shrink_by_effect(mrecs) if r["effect"] == "rate.amplifier")
        if h["scored"]:
            out.append(M(f"{what}, rate.amplifier: cases scored for how far: median relative error of the predicted "
                         "shrink, truth inside the 90 % interval",
                         f"{h['scored']}: {h['median_error']:.2f}, {h['inside']} of {h['scored']}", "<= 0.35",
                         _met(h["median_error"] <= 0.35)))
    from tip_joint import score as joint_score

    for folder, key, what in [
        ("benchmarks/gap_tip/joint_20261203", "gap_joint_20261203",
         "first contact, before the joint game's rule (all named effects joined)"),
        ("benchmarks/gap_tip/joint_20261203_rule", "gap_joint_20261203_rule",
         "the same cases again with the rule (an effect whose model alone makes Table 3 worse is left out of all "
         "together), made for them"),
        ("benchmarks/gap_tip/joint_20261204", "gap_joint_20261204",
         "a seed never used, scored once with the rule (first contact)"),
        ("benchmarks/gap_tip/joint_20261205", "gap_joint_20261205",
         "a seed never used, scored once after a member forced on was identified with the H(q) selection instead "
         "of the held form (first contact)"),
        ("benchmarks/gap_tip/joint_20261222", "gap_joint_20261222",
         "a seed never used, scored once with the widened interval of 2026-12-06 (first contact)"),
    ]:
        jsrc = f"{folder}/joint_cases.jsonl.gz"
        if not (ROOT / jsrc).exists():
            continue
        js = joint_score([json.loads(x) for x in gzip.open(ROOT / jsrc, "rt")])
        seed = COMMANDS[key].split("--seed ")[1].split()[0]
        out.append(Fig(f"gap diagnostic, joint tip tier, seed {seed} ({js['n']} cases with 2-3 effects; {what}): "
                       f"median relative error of the all-together shrink ({js['n_scored']} cases with a real joint "
                       "tip consequence); true joint shrink inside its 90 % interval; runaways (error > 1)",
                       f"{js['median_error']:.2f}; {js['coverage']:.2f}; {js['runaways']}", "<= 0.25; >= 0.80",
                       _met(js["median_error"] <= 0.25 and js["coverage"] >= 0.8), jsrc, COMMANDS[key],
                       DATES[key]))
    recs = [json.loads(x) for x in gzip.open(ROOT / "benchmarks/gap_tip/tip_cases.jsonl.gz", "rt")]
    bsrc = "benchmarks/gap_tip/amplifier_blind.jsonl.gz"
    if (ROOT / bsrc).exists():
        ab = [json.loads(x) for x in gzip.open(ROOT / bsrc, "rt")]
        ad = [r for r in ab if r["adopted"]]
        if ad:
            better = sum(r["table3_auto"] < r["table3_off"] for r in ad)
            out.append(Fig(f"amplifier member of the voltage link at first contact: the first {len(ab)} rate.amplifier "
                           "tip cases of a seed not used in its development; adopted; where adopted, Table 3 lower "
                           "than with the member off; median Table 3 member off -> auto (effect-free twins)",
                           f"{len(ad)} of {len(ab)}; {better} of {len(ad)}; "
                           f"{statistics.median(r['table3_off'] for r in ad):.2f} -> "
                           f"{statistics.median(r['table3_auto'] for r in ad):.2f} "
                           f"({statistics.median(r['table3_twin'] for r in ad):.2f}) points", "", "measured", bsrc,
                           COMMANDS["amplifier_blind"], DATES["amplifier_blind"]))
    absrc = "benchmarks/gap_tip/absorption_blind.jsonl.gz"
    if (ROOT / absrc).exists():
        ab = [json.loads(x) for x in gzip.open(ROOT / absrc, "rt")]
        ad = [r for r in ab if r["adopted"]]
        if ad:
            better = sum(r["table3_auto"] < r["table3_off"] for r in ad)
            out.append(Fig(f"absorption member of the charge link at first contact: the first {len(ab)} "
                           "slow.absorption tip cases of a seed not used in its development; adopted; where adopted, "
                           "Table 3 lower than with the member off; median Table 3 member off -> auto (effect-free "
                           "twins)", f"{len(ad)} of {len(ab)}; {better} of {len(ad)}; "
                           f"{statistics.median(r['table3_off'] for r in ad):.2f} -> "
                           f"{statistics.median(r['table3_auto'] for r in ad):.2f} "
                           f"({statistics.median(r['table3_twin'] for r in ad):.2f}) points", "", "measured", absrc,
                           COMMANDS["absorption_blind"], DATES["absorption_blind"]))
    for key, member, effect in (("temperature_blind", "temperature member of the charge link", "slow.temperature"),
                                ("stress_blind", "stress member of the load link", "load.stress_hysteresis")):
        src_ = f"benchmarks/gap_tip/{key}.jsonl.gz"
        if not (ROOT / src_).exists():
            continue
        rs = [json.loads(x) for x in gzip.open(ROOT / src_, "rt")]
        ad = [r for r in rs if r["adopted"]]
        better = sum(r["table3_auto"] < r["table3_off"] for r in ad)
        out.append(Fig(f"{member} (off by default) at first contact: the first {len(rs)} {effect} tip cases of a seed "
                       "not used in its development, the member decided by the data; adopted; where adopted, Table 3 "
                       "lower than with the member off; median Table 3 member off -> auto (effect-free twins); "
                       "adopted on the effect-free twins",
                       f"{len(ad)} of {len(rs)}; {better} of {len(ad)}; "
                       + (f"{statistics.median(r['table3_off'] for r in ad):.2f} -> "
                          f"{statistics.median(r['table3_auto'] for r in ad):.2f} "
                          f"({statistics.median(r['table3_twin'] for r in ad):.2f}) points" if ad else "-")
                       + f"; {sum(bool(r['adopted_twin']) for r in rs)} of {len(rs)}", "", "measured", src_,
                       COMMANDS[key], DATES[key]))
    stress = "load.stress_hysteresis"
    for key, what, e in (("stress_first_20261206", "the stress member forced on identified with the H(q) selection "
                          "(first contact: 8 load.stress_hysteresis tip cases of a seed not used before)", stress),
                         ("stress_wide_20261206", "the same seed's costly case the narrow blocked form left unnamed, "
                          "with the wider form (first contact of the form)", stress),
                         ("stress_solve_20261206", "the same 8 cases with the member's load solved with a ridge "
                          "chosen on the calibration trials (development cases of the solve)", stress),
                         ("stress_first_20261208", "the ridge load solve at first contact (the first 10 "
                          "load.stress_hysteresis tip cases of a seed not used before)", stress),
                         ("temperature_tip_20261215", "slow.temperature with the estimator's temperature member forced "
                          "on for how far it shrinks (first contact: the first 8 slow.temperature tip cases of a seed "
                          "not used before)", "slow.temperature")):
        src_ = f"benchmarks/gap_tip/{key}.jsonl.gz"
        if not (ROOT / src_).exists():
            continue
        from selfsense.gap.blind import COST_POINTS, _truth

        rs = [json.loads(x) for x in gzip.open(ROOT / src_, "rt")]
        costly = [r for r in rs if r["true_shrink"] >= COST_POINTS]
        named = [r for r in rs if r["top"] == e and e in r["predicted_shrink"]]
        errs = [abs(r["predicted_shrink"][e] - _truth(r, e)) / abs(_truth(r, e)) for r in named if _truth(r, e)]
        out.append(Fig(f"gap diagnostic, tip tier, {what}: cases costing >= 3 points named; median relative error "
                       "of the predicted shrink over the cases named (largest cost)",
                       f"{sum(r['top'] == e for r in costly)} of {len(costly)}; "
                       + (f"{statistics.median(errs):.2f} ({len(errs)} cases)" if errs else "-")
                       + f" ({max(r['true_shrink'] for r in rs):.1f} points)", ">= 90 %; <= 0.35",
                       _met(sum(r["top"] == e for r in costly) >= 0.9 * len(costly) and bool(errs)
                            and statistics.median(errs) <= 0.35), src_,
                       COMMANDS[key], DATES[key]))
    for key, what in (("creep_member_8080", "development cases (7 slow.creep tip cases of seed 8080)"),
                      ("creep_member_first_20261209", "first contact (the first 8 slow.creep tip cases of a seed not "
                       "used before)")):
        src_ = f"benchmarks/gap_tip/{key}.jsonl"
        if not (ROOT / src_).exists():
            continue
        rs = [json.loads(x) for x in (ROOT / src_).read_text().splitlines() if x.strip()]

        def med(k, rs=rs):
            return statistics.median(r["table3_disp"][k] for r in rs)

        out.append(Fig(f"charge-free creep, measured before a creep member is built, {what}: displacement Table 3 "
                       "of the contact validation trials (the tip tier's four calibration trials, not the thesis protocol), median: "
                       "default estimator; a creep bank on Q and V_p "
                       "(default / offset-drift member off); effect-free twin (default / offset-drift off); cases "
                       "where the offset-drift member is adopted",
                       f"{med('case_default'):.2f} %; {med('member_default'):.2f} / {med('member_drift_off'):.2f} %; "
                       f"{med('twin_default'):.2f} / {med('twin_drift_off'):.2f} %; "
                       f"{sum(r['member']['offset_drift_adopted_default'] for r in rs)} of {len(rs)}",
                       "", "measured", src_, COMMANDS[key], DATES[key]))
    key = "creep_member_built_first_20261210"
    src_ = f"benchmarks/gap_tip/{key}.jsonl"
    if (ROOT / src_).exists():
        rs = [json.loads(x) for x in (ROOT / src_).read_text().splitlines() if x.strip()]

        def pair(k, rs=rs):
            return (f"{statistics.median(r[k]['displacement'] for r in rs):.2f} / "
                    f"{statistics.median(r[k]['force'] for r in rs):.2f} %")

        out.append(Fig(f"charge-free creep member (config tip_creep), first contact ({len(rs)} slow.creep tip cases of "
                       "a seed not used before; the tip tier's four calibration trials, not the thesis protocol): "
                       "Table 3 of the contact validation trials, median displacement / force: member off; default; "
                       "effect-free twins (default); member adopted on cases / on twins; offset-drift member dropped "
                       "beside it",
                       f"{pair('case_off')}; {pair('case_auto')}; {pair('twin_auto')}; "
                       f"{sum(r['case_auto']['tip_creep'] for r in rs)} / {sum(r['twin_auto']['tip_creep'] for r in rs)}"
                       f" of {len(rs)}; {sum(r['case_auto']['offset_drift_dropped'] for r in rs)}",
                       "", "measured", src_, COMMANDS[key], DATES[key]))
    key = "creep_chain_first_20261211"
    src_ = f"benchmarks/gap_tip/{key}.jsonl.gz"
    if (ROOT / src_).exists():
        from selfsense.gap.blind import _tip_scored

        rs = [json.loads(x) for x in gzip.open(ROOT / src_, "rt")]
        floor, rows = _tip_scored(rs)
        sc = [r for r in rows if r["scored"]]
        med = statistics.median(r["error"] for r in sc) if sc else float("nan")
        out.append(Fig(f"charge-free creep, how far it shrinks with the creep member in the chain, first contact "
                       f"({len(rs)} slow.creep tip cases of a seed not used before): named top-1; cases with a real "
                       "tip consequence (> 3 tip noise floors of these records); median relative error of the "
                       "predicted tip shrink over the cases named with one; true shrink inside the 90 % interval",
                       f"{sum(r['named'] for r in rows)} of {len(rs)}; {sum(r['tip_real'] for r in rows)} (floor "
                       f"{floor:.2f} points); " + (f"{med:.2f}" if sc else "-") + f" over {len(sc)}; "
                       f"{sum(r['inside'] for r in sc)} of {len(sc)}",
                       "<= 0.35 per effect family (over a campaign)", "measured", src_, COMMANDS[key], DATES[key]))
    nsrc_ = "benchmarks/gap_tip/absorption_null.jsonl.gz"
    if (ROOT / nsrc_).exists():
        nl = [json.loads(x) for x in gzip.open(ROOT / nsrc_, "rt")]
        fams = sorted({r["family"] for r in nl})
        out.append(Fig(f"absorption member on devices without an absorption branch ({len(nl)} devices, "
                       f"{len(fams)} families, clean and drift presets, thesis protocol): adopted (false adoptions)",
                       f"{sum(r['supported'] for r in nl)} of {len(nl)}", "", "measured", nsrc_,
                       COMMANDS["absorption_null"], DATES["absorption_null"]))
    amsrc = "benchmarks/gap_tip/absorption_member_90210.jsonl.gz"
    if (ROOT / amsrc).exists() and seed_90210:
        from selfsense.gap.blind import _truth

        am = [json.loads(x) for x in gzip.open(ROOT / amsrc, "rt")]
        camp = {r["case"]: r for r in (json.loads(x) for x in gzip.open(
            ROOT / "benchmarks/gap_tip/seed_90210/tip_cases.jsonl.gz", "rt"))}
        e = "slow.absorption"
        now = [abs(r["predicted_shrink"][e] - _truth(r, e)) / abs(_truth(r, e)) for r in am
               if r["top"] == e and _truth(r, e)]
        out.append(Fig(f"gap diagnostic, tip tier, seed 90210, the {len(am)} slow.absorption cases rescored with the "
                       "absorption member carried by the default estimator: the effect's cost in Table 3 (case minus "
                       "its effect-free twin), median, campaign record -> now; median relative error of the "
                       "predicted shrink (named top-1) now",
                       f"{statistics.median(camp[r['case']]['true_shrink'] for r in am):.2f} -> "
                       f"{statistics.median(r['true_shrink'] for r in am):.2f} points; {statistics.median(now):.2f} "
                       f"({len(now)} cases)", "<= 0.35", _met(statistics.median(now) <= 0.35), amsrc,
                       COMMANDS["absorption_member"], DATES["absorption_member"]))
    ssim = "benchmarks/gap_tip/stress_simfix.jsonl.gz"
    if (ROOT / ssim).exists():
        st = [json.loads(x) for x in gzip.open(ROOT / ssim, "rt")]
        ct = cost_table(st)
        costly = sum(r["costly"] for r in ct)
        named = sum(r["named"] for r in ct)
        out.append(Fig(f"gap diagnostic, tip tier, load.stress_hysteresis cases rescored after the simulator's stress "
                       f"fix ({len(st)} cases, the current estimator): the effect's cost in Table 3 (case minus its "
                       f"effect-free twin), median (largest); cases costing >= 3 points named",
                       f"{statistics.median(r['true_shrink'] for r in st):.2f} "
                       f"({max(r['true_shrink'] for r in st):.2f}) points; {named} of {costly}", ">= 90 % named",
                       _met(costly > 0 and named >= 0.9 * costly), ssim, COMMANDS["tip_stress"],
                       DATES["tip_stress"]))
    psrc = "benchmarks/gap_tip/preload_relay_fix.jsonl.gz"
    if (ROOT / psrc).exists():
        pl = [json.loads(x) for x in gzip.open(ROOT / psrc, "rt")]
        camp = {r["case"]: r for r in (json.loads(x) for x in gzip.open(
            ROOT / "benchmarks/gap_tip/seed_14142/tip_cases.jsonl.gz", "rt"))}
        ct = cost_table(pl)
        costly = sum(r["costly"] for r in ct)
        named = sum(r["named"] for r in ct)
        out.append(Fig(f"gap diagnostic, tip tier, seed 14142, the {len(pl)} costliest hysteresis.preload cases "
                       "rescored after the simulator's relay fix (the current code): the effect's cost in Table 3 "
                       "(case minus its effect-free twin), median, campaign record -> now; cases costing >= 3 points "
                       "named now",
                       f"{statistics.median(camp[r['case']]['true_shrink'] for r in pl):.2f} -> "
                       f"{statistics.median(r['true_shrink'] for r in pl):.2f} points; {named} of {costly}",
                       ">= 90 % named", _met(costly > 0 and named >= 0.9 * costly), psrc, COMMANDS["tip_preload"],
                       DATES["tip_preload"]))
    asrc = "benchmarks/gap_tip/amplifier_member.jsonl.gz"
    if (ROOT / asrc).exists():
        amp = [json.loads(x) for x in gzip.open(ROOT / asrc, "rt")]
        old = {r["case"]: r for r in recs if r["seed"] == 4711}
        now = [r["true_shrink"] for r in amp]
        was = [old[r["case"]]["true_shrink"] for r in amp if r["case"] in old]
        if now and was:
            out.append(Fig(f"gap diagnostic, tip tier, rate.amplifier cases rescored with the amplifier member of the "
                           f"voltage link carried by the default estimator ({len(amp)} cases): the effect's cost in "
                           "Table 3 (case minus its effect-free twin), median, campaign record -> now",
                           f"{statistics.median(was):.2f} -> {statistics.median(now):.2f} points", "",
                           "measured", asrc, COMMANDS["tip_amplifier"], DATES["tip_amplifier"]))
    ssrc = "benchmarks/stage_chain/tip/summary.md"
    txt = (ROOT / ssrc).read_text()
    m = re.search(r"cases: (\d+);.*?effect named \(top-1\) (\d+)", txt)
    e = re.search(r"over the (\d+) named cases.*?\*\*([0-9.]+)\*\*", txt, re.S)
    if m and e:
        sup = ("; **superseded**: a member the estimator carried was given a predicted shrink of 0 (an error of 1 by "
               "construction); the seed-90210 tip tier above scores leakage and offset drift with the member's own "
               "contribution") if seed_90210 else ""
        out.append(Fig(f"stage chain, tip tier on the charge link's effects ({m.group(1)} cases, leakage and offset "
                       "drift): named top-1; median relative error of the predicted tip shrink "
                       f"({e.group(1)} scored){sup}", f"{m.group(2)} of {m.group(1)}; {float(e.group(2)):.2f}",
                       "<= 0.25", _met(float(e.group(2)) <= 0.25) + (" (superseded)" if sup else ""), ssrc,
                       COMMANDS["stage_tip"], DATES["stage_chain"]))
    return out


def external_figures() -> list[Fig]:
    src = "benchmarks/external/fit_external.md"
    p = ROOT / src
    if not p.exists():
        return []
    out = []
    for line in p.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 5 or not line.startswith("|") or cells[0] in ("pair",) or set(cells[0]) <= set("-"):
            continue
        sel, lin, pi = (float(x.split("/")[0]) for x in cells[2:5])
        out.append(Fig(f"real record pair {cells[0]}: RMS error of the selected H ({cells[1]}), of a straight line, "
                       "of a plain PI-10, out of sample", f"{sel:.2f} / {lin:.2f} / {pi:.2f} % of range",
                       "selected < line and < PI-10", _met(sel < lin and sel < pi), src, COMMANDS["external"],
                       DATES["external"]))
    return out


def realtime_figures() -> list[Fig]:
    """Per-sample cost of the stream (Python) and of the generated C for every model kind, from RESULTS.json (b)."""
    r = _read_json("benchmarks/RESULTS.json")
    src, cmd, date = "benchmarks/RESULTS.md", r.get("command", COMMANDS["results"]), r["machine"]["date"][:10]
    out = []
    for k in r["b"].get("kinds", []):
        if "us_100" not in k:
            continue
        default = k["label"].startswith("default")
        c = f"; C {k['c_ns'] / 1e3:.3f} us" if "c_ns" in k else "; C not measured (no compiler)"
        out.append(Fig(f"{k['label']} ({k['model']}) on `{k['dataset']}`: Python stream in blocks of 100 samples; "
                       "generated C", f"{k['us_100']:.2f} us{c}",
                       "<= 1 us Python, <= 0.2 us C" if default else "",
                       _met(k["us_100"] <= 1.0 and k.get("c_ns", 1e9) <= 200) if default else "measured",
                       src, cmd, date))
    return out


def collect() -> dict[str, list[Fig]]:
    res = results_figures()
    return {"speed": res["speed"], "bundled": res["bundled"], "realtime": realtime_figures(),
            "cross_device": cross_device_figures() + error_cause_figures(),
            "stage_chain": stage_chain_figures() + hold_rows_figures(), "gap": gap_figures(),
            "external": external_figures()}


TITLES = {"cross_device": "Accuracy across virtual devices (thesis Table 3 per truth family)",
          "stage_chain": "Accuracy on the thesis protocol, clean and with leakage + offset drift + creep",
          "bundled": "The bundled virtual tweezer `tweezer_sim`",
          "gap": "Sim-to-real gap diagnostic (blind campaigns)",
          "external": "Hysteresis models on real measurements made by others",
          "realtime": "Real time: cost per sample of the stream and of the generated C, per model kind",
          "speed": "Speed and memory"}
HEAD = "| figure | measured | target | status |\n|---|---|---|---|"
HEAD_SRC = "| figure | measured | target | status | source | command | date |\n|---|---|---|---|---|---|---|"


def render_block(name: str, figs: dict[str, list[Fig]]) -> str:
    """The body of the block ``name``: one group's table, or for ``all`` every group in one table (a bold row per
    group), followed by the command and date of each group's source."""
    groups = list(TITLES) if name == "all" else [name]
    for g in groups:
        if g not in figs:
            raise SystemExit(f"benchmarks/figures.py: unknown figure block {name!r} (groups: {', '.join(TITLES)})")
    rows, sources, n_history = [HEAD], [], 0
    for g in groups:
        shown = [f for f in figs[g] if not (name == "all" and f.history)]
        n_history += len(figs[g]) - len(shown)
        if not shown:
            continue
        if len(groups) > 1:
            rows.append(f"| **{TITLES[g]}** | | | |")
        rows += [f.row(with_source=False) for f in shown]
        for f in shown:
            src = f"`{f.command}` ({f.date}; [{f.source}](../{f.source}))"
            if src not in sources:
                sources.append(src)
    lead = ("Generated by `python benchmarks/figures.py` from the benchmark outputs (do not edit by hand); every row's "
            "source, command and date: [benchmarks/FIGURES.md](../benchmarks/FIGURES.md)."
            + (f" Each benchmark's first contact and its score with the current code are shown; {n_history} rows of "
               "scorings in between are in benchmarks/FIGURES.md and docs/cross_device.md." if n_history else ""))
    return "\n".join([lead, "", *rows, "", "Measured by:", *[f"- {x}" for x in sources]]) + "\n"


def render_figures_md(figs: dict[str, list[Fig]]) -> str:
    L = ["# Measured figures", "",
         "Generated by `python benchmarks/figures.py` from the committed benchmark outputs; the README and docs/ quote "
         "these rows (their blocks are generated by the same script, and `tests/test_figures.py` fails when any of them "
         "is out of date). Measured on the project's 2-core machine; rates vary with the machine's load.", ""]
    for g, title in TITLES.items():
        if not figs.get(g):
            continue
        L += [f"## {title}", "", HEAD_SRC]
        L += [f.row() for f in figs[g]]
        L.append("")
    return "\n".join(L)


def _fix_links(text: str, page: str) -> str:
    """Links in a block are written as from a docs/ page (``../benchmarks/...``); make them relative to ``page``."""
    depth = page.count("/")
    return text.replace("](../", "](" + "../" * depth)


def updated_pages(figs) -> dict[str, str]:
    """page -> its text with every figure block regenerated."""
    out = {}
    for page in PAGES:
        p = ROOT / page
        if not p.exists():
            continue
        text = p.read_text()
        new = BLOCK.sub(lambda m: m.group(1) + _fix_links(render_block(m.group("name"), figs), page) + m.group(4),
                        text)
        out[page] = new
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only compare; exit 1 naming what is out of date")
    ap.add_argument("--root", type=Path, default=None, help="repository root (default: this file's parent's parent)")
    a = ap.parse_args(argv)
    global ROOT
    if a.root is not None:
        ROOT = a.root.resolve()
    figs = collect()
    targets = {"benchmarks/FIGURES.md": _links_for_figures_md(render_figures_md(figs))}
    targets.update(updated_pages(figs))
    stale = [k for k, v in targets.items() if not (ROOT / k).exists() or (ROOT / k).read_text() != v]
    shot = _screenshot_problem()
    if shot:
        print(shot, file=sys.stderr)
        if a.check:
            return 1
    if a.check:
        for k in stale:
            print(f"{k}: figure table out of date with the benchmark outputs; run python benchmarks/figures.py",
                  file=sys.stderr)
        return 1 if stale else 0
    for k in stale:
        (ROOT / k).write_text(targets[k])
        print(f"wrote {k}")
    return 0


def _screenshot_problem() -> str:
    """The report screenshot in docs/img must show the Table 3 of the current default (RESULTS.json's pipeline run);
    its sidecar JSON is written with it by benchmarks/screenshot.py."""
    side = ROOT / "docs" / "img" / "report_tweezer_sim_top.json"
    d = _read_json("benchmarks/RESULTS.json").get("d", {})
    if not d.get("available"):
        return ""
    want = {k: d["table3_rows"][k][2] for k in ("displacement", "force")}
    have = json.loads(side.read_text())["table3_percent_of_range"] if side.exists() else None
    if have != want:
        return (f"docs/img/report_tweezer_sim_top.png shows Table 3 {have}, the current default gives {want}: run "
                "selfsense run --cores 2 && python benchmarks/screenshot.py")
    return ""


def _links_for_figures_md(text: str) -> str:
    """FIGURES.md lives in benchmarks/: its source links are relative to that folder."""
    return text.replace("](../benchmarks/", "](").replace("](benchmarks/", "](")


if __name__ == "__main__":
    sys.exit(main())
