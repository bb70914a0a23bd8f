"""The house's rooms depend only on rooms below them (every import of src/selfsense, function-level ones included):
no import circle between subpackages, the truth simulator never sees the estimator or the diagnostic, and only the
command line (selfsense.cli) sits above the library."""
from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "src" / "selfsense"
#: rooms from the bottom up; a room may import rooms of a lower rank only (and itself)
RANK = {"selfsense": 0, "determinism": 0, "parallel": 0, "process": 0, "signals": 1, "io": 2, "hysteresis": 2, "mechanics": 2, "chain": 3,
        "sensing": 4, "sim": 4, "report": 5, "stages": 6, "gap": 7, "devices": 8, "cli": 9, "__main__": 10}


def _room(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "selfsense"


def _edges() -> dict[str, set[str]]:
    edges: dict[str, set[str]] = defaultdict(set)
    for f in ROOT.rglob("*.py"):
        rel = f.relative_to(ROOT.parent).with_suffix("")
        mod = ".".join(rel.parts)
        pkg = mod[: -len(".__init__")] if f.name == "__init__.py" else mod.rsplit(".", 1)[0]
        src = _room(mod.removesuffix(".__init__"))
        for n in ast.walk(ast.parse(f.read_text())):
            targets = []
            if isinstance(n, ast.ImportFrom):
                if n.level:
                    base = pkg.split(".")[: len(pkg.split(".")) - (n.level - 1)]
                    targets = [".".join(base + ([n.module] if n.module else []))]
                elif n.module:
                    targets = [n.module]
            elif isinstance(n, ast.Import):
                targets = [a.name for a in n.names]
            for t in targets:
                if t == "selfsense" or t.startswith("selfsense."):
                    edges[src].add(_room(t))
    return edges


def test_every_room_is_ranked():
    rooms = {p.stem if p.is_file() else p.name for p in ROOT.iterdir()
             if (p.suffix == ".py" or (p.is_dir() and (p / "__init__.py").exists()))} - {"__init__"}
    assert rooms <= set(RANK), f"rooms without a rank: {sorted(rooms - set(RANK))}"


def test_rooms_depend_only_on_rooms_below_them():
    bad = [f"{a} -> {b}" for a, bs in _edges().items() for b in bs
           if b != a and RANK.get(b, 99) >= RANK.get(a, -1) and b != "selfsense"]
    assert not bad, "imports that point up or sideways: " + ", ".join(sorted(bad))


def test_the_truth_simulator_never_imports_the_estimator_or_the_diagnostic():
    assert not (_edges()["sim"] & {"sensing", "gap", "chain", "stages"}), _edges()["sim"]


#: the diagnostic's package stays under this many lines (src/selfsense/gap/*.py, counted as ``wc -l`` counts them)
GAP_MAX_LINES = 3000


def test_the_gap_package_stays_under_its_line_limit():
    n = sum(f.read_bytes().count(b"\n") for f in (ROOT / "gap").glob("*.py"))
    assert n < GAP_MAX_LINES, f"src/selfsense/gap/*.py has {n} lines; the limit is {GAP_MAX_LINES} (under it)"
