"""Problems found in a raw dataset and the exception that carries them.

A :class:`Problem` is one violation of the raw-dataset contract (``docs/data_format.md``,
docs/data_format.md); it names the file, the column or key, the row where it
applies and what was expected, and prints as exactly one line::

    trials.csv: column 'role', row 3: expected 'calibration' or 'validation', found 'calib'

Row numbers are 1-based *data* rows (the header line of a CSV is not counted), so row 1 is the first
sample of a log or the first trial of ``trials.csv``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["Problem", "ContractError", "truncate", "MAX_FOUND_CHARS"]


#: longest rendering of a found value in a message (a YAML alias bomb or a 1 MB cell stays one short line)
MAX_FOUND_CHARS = 120


def truncate(text: str, limit: int = MAX_FOUND_CHARS) -> str:
    """``text`` cut to ``limit`` characters with a marker saying how much was left out."""
    text = str(text)
    if len(text) <= limit:
        return text
    return text[:limit] + f"... ({len(text) - limit} more characters)"


def _fmt_found(found: Any) -> str:
    if isinstance(found, str):
        if len(found) > MAX_FOUND_CHARS:
            return repr(found[:MAX_FOUND_CHARS]) + f"... ({len(found) - MAX_FOUND_CHARS} more characters)"
        return repr(found)
    if isinstance(found, float):
        return f"{found:.6g}"
    if isinstance(found, (dict, list, tuple, set)):
        import reprlib

        r = reprlib.Repr()
        r.maxlevel, r.maxdict, r.maxlist, r.maxstring, r.maxother = 2, 4, 4, 40, 40
        return truncate(r.repr(found))
    return truncate(str(found))


@dataclass(frozen=True)
class Problem:
    """One violation of the raw-dataset contract.

    Attributes
    ----------
    file : path of the offending file relative to the dataset folder (e.g. ``"trials.csv"``).
    field : column name (tables, logs) or dotted key (``rig.yaml``), or ``None`` for a file-level problem.
    row : 1-based data row, or ``None`` when the problem is not about one row.
    expected : human-readable statement of what the contract requires.
    found : what was found instead (optional; long values are truncated in the message).
    level : ``"error"`` (the dataset is refused) or ``"warning"`` (reported, the run goes on).
    """

    file: str
    field: str | None
    row: int | None
    expected: str
    found: Any = None
    level: str = "error"

    def __str__(self) -> str:
        parts = [str(self.file)]
        loc = []
        if self.field:
            kind = "key" if str(self.file).endswith((".yaml", ".yml")) else "column"
            loc.append(f"{kind} {truncate(repr(str(self.field)), 80)}")
        if self.row is not None:
            loc.append(f"row {self.row}")
        head = ", ".join(loc)
        msg = f"expected {self.expected}"
        if self.found is not None:
            msg += f", found {_fmt_found(self.found)}"
        text = f"{parts[0]}: {head}: {msg}" if head else f"{parts[0]}: {msg}"
        return " ".join(text.split())  # always one line

    @property
    def is_warning(self) -> bool:
        return self.level == "warning"


class ContractError(ValueError):
    """A dataset (or one of its files) violates the raw-dataset contract.

    ``.problems`` is the full list of :class:`Problem`; the message lists them all, one per line.
    """

    def __init__(self, problems: list[Problem] | Problem, context: str | None = None):
        if isinstance(problems, Problem):
            problems = [problems]
        self.problems: list[Problem] = list(problems)
        n = len(self.problems)
        head = f"{context}: " if context else ""
        head += f"{n} contract problem{'s' if n != 1 else ''}"
        super().__init__(head + ("\n" + "\n".join(str(p) for p in self.problems) if n else ""))
