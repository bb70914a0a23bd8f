"""selfsense.io: reading and validating raw datasets (docs/data_format.md) and writing artefacts atomically.

Knows no physics beyond the unit conversions of docs/data_format.md. See docs/data_format.md.
"""
from .atomic import (RawDataWriteError, assert_not_in_raw, atomic_write, atomic_write_bytes, atomic_write_text,
                     dumps_json, parquet_bytes, write_bytes_atomic, write_json_atomic, write_parquet_atomic,
                     savefig_atomic, write_text_atomic)
from .budget import FIGURE_MAX_ROWS, GAP_MAX_SAMPLES, block_mean, read_parquet_decimated
from .outputs import MARKER, OutputError, check_output_dir, check_output_file, output_dir, output_lock
from .dataset import SI_COLUMNS, Dataset, check_dataset, load_dataset, to_si, trial_signals, validate_dataset
from .errors import ContractError, Problem
from .logs import check_log, check_signals, read_log
from .rig import CANONICAL_COLUMNS, ActuatorCatalog, ChannelMap, Reference, Rig, check_rig, load_rig, parse_rig
from .trials import TRIAL_COLUMNS, check_trials, load_trials

__all__ = [
    "Problem", "ContractError", "Rig", "Reference", "ActuatorCatalog", "ChannelMap", "load_rig", "parse_rig",
    "check_rig", "load_trials", "check_trials", "read_log", "check_log", "check_signals", "validate_dataset",
    "load_dataset", "Dataset", "trial_signals", "to_si", "SI_COLUMNS", "CANONICAL_COLUMNS", "TRIAL_COLUMNS",
    "atomic_write", "atomic_write_bytes", "atomic_write_text", "write_parquet_atomic", "write_json_atomic",
    "check_dataset", "dumps_json", "write_text_atomic", "write_bytes_atomic", "parquet_bytes", "assert_not_in_raw", "RawDataWriteError",
]
