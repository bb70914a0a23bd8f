"""``selfsense init DIR``: write a template dataset folder for your own rig (rig.yaml, trials.csv, README.txt).

The templates carry the keys, columns and allowed values of the data contract (docs/data_format.md) with
comments; the numbers are those of the bundled virtual tweezer and must be replaced by your rig's. Copy your DAQ
logs into DIR, edit trials.csv to list them, then run ``selfsense validate DIR`` until it prints OK.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["main", "write_template", "RIG_TEMPLATE", "TRIALS_TEMPLATE"]

RIG_TEMPLATE = """\
# rig.yaml: the acquisition rig of dataset '{name}' (docs/data_format.md). SI units; replace every number.
dataset: {name}                 # must equal the folder name
sample_rate_hz: 1000.0          # DAQ sample rate [Hz]
shunt_resistance_ohm: 1000.0    # charge-measurement shunt R_s [ohm] (thesis eqs. 56-57)
amplifier_gain: 15.0            # HV amplifier gain [V/V]: actuator-side voltage V_c = gain * u_cmd
inamp_gain: 5.0                 # instrumentation amplifier gain on the shunt [V/V]: v_shunt = gain * V_s
n_actuators: 5                  # stacks driven in parallel (thesis: 5)
reference:
  laser_m_per_v: 0.002          # laser displacement sensor [m/V] (tip displacement = 2 * this * laser)
  load_cell_n_per_v: 0.1        # load cell [N/V]
actuator_catalog:               # one stack, from its data sheet
  free_displacement_m: 1.0e-05  # free stroke [m]
  blocked_force_n: 240.0        # blocked force [N]
  stiffness_n_per_m: 2.4e+07    # stiffness [N/m]
  capacitance_f: 2.5e-07        # small-signal capacitance C_p [F]
  max_voltage_v: 150.0          # maximum actuator voltage [V]
tip_free_displacement_m: 0.0065 # free tip opening of the amplified device at max voltage [m]
# Optional (delete what you do not need):
# adc_range_v: 10.0             # +- full scale of the DAQ inputs [V] (saturation checks)
# format: auto                  # auto (by file extension) | csv | parquet | tdms | mat
# drive: {{u_cmd_min_v: -1.0, u_cmd_max_v: 10.5}}  # plausible u_cmd range [V]: widen for a bipolar drive or a
#                               # logged amplifier output (then amplifier_gain: 1)
# channel_map:                  # your file's column names and scales -> the canonical channels
#   columns: {{t: Time_ms, u_cmd: AO0, v_shunt: AI1_mV}}
#   scale:   {{t: 1.0e-3, v_shunt: 1.0e-3}}    # canonical value = scale * file value
"""

TRIALS_TEMPLATE = """\
trial,file,role,tip,object_mm,reference,signal
cal_free,cal_free.csv,calibration,free,,displacement,sine
cal_blocked,cal_blocked.csv,calibration,blocked,,force,sine
val_disp_object,val_disp_object.csv,validation,object,2,displacement,mixed
val_force_object,val_force_object.csv,validation,object,2,force,steps
"""

README_TEMPLATE = """\
Dataset '{name}' for selfsense (template written by `selfsense init`).

1. Edit rig.yaml: every number is an example (the bundled virtual tweezer); replace it by your rig's.
2. Put one DAQ log per trial here (CSV, Parquet, TDMS or MAT) with the channels, in SI units,
     t [s], u_cmd [V, amplifier input], v_shunt [V, in-amp output], laser [V], load_cell [V], relay [0/1]
   (other names or scales: rig.yaml channel_map; extra channels are ignored with a note; an oscilloscope
   CSV with preamble lines before the header is read). A bipolar drive, or u_cmd logged at the amplifier
   output: rig.yaml drive: {{u_cmd_min_v: ..., u_cmd_max_v: ...}}.
3. Edit trials.csv: one row per log. Allowed values:
     role       calibration | validation
     tip        free | blocked | object        (object_mm: object size [mm] when tip = object, else empty)
     reference  displacement | force           (which reference sensor is valid in this trial)
     signal     sine | mixed | steps | other
   The method needs at least one calibration trial with tip = free (H(q) calibration) and calibration trials
   with both references (the coefficient regression); validation trials are scored (Table 3).
4. selfsense validate {path}     (exit 0 and an OK line, or one line per problem)
5. selfsense run --config datasets='[{name}]' raw_dir={raw}
The full contract: docs/data_format.md of the selfsense repository.
"""


def write_template(target: str | Path, force: bool = False) -> list[Path]:
    """Write ``rig.yaml``, ``trials.csv`` and ``README.txt`` into ``target`` (created); refuses to overwrite."""
    d = Path(target)
    name = d.resolve().name
    files = {"rig.yaml": RIG_TEMPLATE.format(name=name), "trials.csv": TRIALS_TEMPLATE,
             "README.txt": README_TEMPLATE.format(name=name, path=target, raw=d.parent.as_posix() or ".")}
    clash = [f for f in files if (d / f).exists()]
    if clash and not force:
        raise FileExistsError(f"{d}: {', '.join(clash)} already exist(s); pass --force to overwrite")
    d.mkdir(parents=True, exist_ok=True)
    out = []
    for f, text in files.items():
        (d / f).write_text(text)
        out.append(d / f)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="selfsense init", description=__doc__.splitlines()[0], allow_abbrev=False,
                                 epilog="The folder name becomes the dataset name (rig.yaml 'dataset').")
    ap.add_argument("dir", help="dataset folder to create, e.g. data/raw/myrig")
    ap.add_argument("--force", action="store_true", help="overwrite existing rig.yaml / trials.csv / README.txt")
    a = ap.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        paths = write_template(a.dir, force=a.force)
    except FileExistsError as exc:
        print(f"selfsense init: error: {exc}", file=sys.stderr)
        return 2
    for p in paths:
        print(f"wrote {p}")
    print(f"next: copy your logs into {a.dir}, edit trials.csv and rig.yaml, then: selfsense validate {a.dir}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
