"""Checks of the pipeline configuration that a JSON schema cannot make (run when the config is loaded).

``workflow/schemas/config.schema.yaml`` checks keys, types and enumerations. :func:`check_config` adds, before
any job runs:

* no YAML aliases in the config files (:mod:`selfsense.io.yamlsafe`), and no shared sub-trees in the parsed
  config (what aliases leave behind when the files were parsed by someone else);
* ``results_dir`` neither equal to, inside, nor containing ``raw_dir`` or any dataset folder, symlinks resolved
  (Snakemake's logs and benchmark files would otherwise land inside the raw data);
* the cvxpy solver of ``calibration.solver`` installed (else the QP fails after the slow steps);

Every failure is a :class:`ConfigError` with a one-line message naming the file or key and the expectation.
"""
from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import Any, Iterable, Mapping

from .errors import truncate
from .yamlsafe import YamlInputError, load_yaml_file

__all__ = ["ConfigError", "check_config", "check_config_files", "check_solver", "load_config_file",
           "schema_problems", "SOLVER_PACKAGES"]

#: cvxpy solver name -> the Python package that provides it (checked without importing cvxpy)
SOLVER_PACKAGES = {"CLARABEL": "clarabel", "OSQP": "osqp", "SCS": "scs", "ECOS": "ecos", "CVXOPT": "cvxopt",
                   "PIQP": "piqp", "PROXQP": "proxsuite", "DAQP": "daqp", "QOCO": "qoco", "GUROBI": "gurobipy",
                   "MOSEK": "mosek", "CPLEX": "cplex", "XPRESS": "xpress", "COPT": "coptpy"}
_MAX_NODES = 100_000


class ConfigError(ValueError):
    """A pipeline configuration that cannot run as written; one-line message."""


def schema_problems(cfg: Mapping, schema: Mapping) -> list[str]:
    """The layered configuration checked against the workflow's JSON schema (``workflow/schemas/config.schema.yaml``)
    before Snakemake reads it: one line per problem naming the key, what was expected and what was found (an unknown
    key with the nearest known one), where Snakemake's own check would print the whole schema. Empty if valid."""
    import difflib

    import jsonschema

    cls = jsonschema.validators.validator_for(schema)
    out: list[str] = []
    for e in sorted(cls(schema).iter_errors(cfg), key=lambda e: [str(p) for p in e.absolute_path]):
        path = ".".join(str(p) for p in e.absolute_path)
        if e.validator == "additionalProperties" and isinstance(e.instance, Mapping):
            known = sorted(e.schema.get("properties", {}))
            for k in sorted(str(k) for k in e.instance if k not in known):
                near = difflib.get_close_matches(k, known, n=1)
                key = f"{path}.{k}" if path else k
                out.append(f"config key {key!r}: expected one of the known keys"
                           + (f" (did you mean {near[0]!r}?)" if near else f" ({', '.join(known)})")
                           + ", found an unknown key")
            continue
        what = {"enum": lambda: "one of " + ", ".join(repr(x) for x in e.validator_value),
                "type": lambda: f"a value of type {e.validator_value}",
                "minimum": lambda: f"a value >= {e.validator_value}",
                "maximum": lambda: f"a value <= {e.validator_value}",
                "exclusiveMinimum": lambda: f"a value > {e.validator_value}",
                "minItems": lambda: f"at least {e.validator_value} item(s)",
                "pattern": lambda: f"a string matching {e.validator_value!r}",
                "required": lambda: "the keys " + ", ".join(repr(x) for x in e.validator_value)}.get(e.validator)
        found = truncate(repr(e.instance), 80)
        out.append(f"config key {path or '(top level)'!r}: expected {what()}, found {found}" if what else
                   f"config key {path or '(top level)'!r}: {truncate(e.message, 200)}")
    return out


def load_config_file(path: str | os.PathLike) -> Any:
    """Read a config YAML file safely (aliases refused, size bounded); raise :class:`ConfigError`."""
    try:
        data = load_yaml_file(path)
    except YamlInputError as e:
        raise ConfigError(str(e)) from None
    if data is not None and not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a YAML mapping of keys, found {type(data).__name__}")
    return data or {}


def check_config_files(paths: Iterable[str | os.PathLike]) -> None:
    """Every config file parses with aliases refused (raise :class:`ConfigError` otherwise)."""
    for p in paths:
        if p is not None and Path(p).is_file():
            load_config_file(p)


def _check_tree(obj: Any) -> None:
    """Refuse shared sub-trees (YAML aliases) and absurdly large configs, in a bounded walk."""
    seen: set[int] = set()
    stack = [("", obj)]
    n = 0
    while stack:
        key, o = stack.pop()
        if isinstance(o, (dict, list)):
            if id(o) in seen:
                raise ConfigError(f"config: key {truncate(key or '<root>', 80)!r}: expected no YAML aliases "
                                  "(a sub-tree used twice), found one")
            seen.add(id(o))
            items = o.items() if isinstance(o, dict) else enumerate(o)
            for k, v in items:
                n += 1
                if n > _MAX_NODES:
                    raise ConfigError(f"config: expected a small configuration (< {_MAX_NODES} entries), found more")
                stack.append((f"{key}.{k}" if key else str(k), v))


def check_solver(solver: Any, key: str = "calibration.solver") -> None:
    """The cvxpy solver must be installed; the message lists the installed ones."""
    if not isinstance(solver, str) or not solver:
        raise ConfigError(f"config: key {key!r}: expected a cvxpy solver name, found {truncate(repr(solver), 80)}")
    pkg = SOLVER_PACKAGES.get(solver.upper())
    if pkg is not None and importlib.util.find_spec(pkg) is not None:
        return
    try:
        import cvxpy

        installed = list(cvxpy.installed_solvers())
    except Exception:  # noqa: BLE001 - cvxpy missing or broken: say so
        installed = []
    if solver.upper() in installed:
        return
    raise ConfigError(f"config: key {key!r}: expected an installed cvxpy solver ({', '.join(installed) or 'none'}), "
                      f"found {truncate(repr(solver), 80)}")


def _resolve(p: str | os.PathLike, base: Path) -> Path:
    p = Path(p).expanduser()
    return (p if p.is_absolute() else base / p).resolve()


def check_config(config: Mapping[str, Any], configfiles: Iterable[str | os.PathLike] = (),
                 workdir: str | os.PathLike = ".") -> None:
    """Run every load-time check of the module docstring; raise :class:`ConfigError` on the first failure."""
    check_config_files(configfiles)
    _check_tree(config)
    if not isinstance(config, Mapping):
        raise ConfigError(f"config: expected a mapping of keys, found {type(config).__name__}")
    base = Path(workdir).resolve()
    raw_s, res_s = config.get("raw_dir", "data/raw"), config.get("results_dir", "results")
    for key, val in (("raw_dir", raw_s), ("results_dir", res_s)):
        if not isinstance(val, str) or not val:
            raise ConfigError(f"config: key {key!r}: expected a folder path, found {truncate(repr(val), 80)}")
    raw, res = _resolve(raw_s, base), _resolve(res_s, base)
    if res == raw or res.is_relative_to(raw) or raw.is_relative_to(res):
        raise ConfigError(f"config: key 'results_dir': expected a folder apart from raw_dir {raw_s!r} (symlinks "
                          f"resolved: {res} vs {raw}), found {res_s!r}; results must never land in the raw data")
    for d in config.get("datasets", []) or []:
        if isinstance(d, str):
            dd = _resolve(os.path.join(raw_s, d), base)
            if res.is_relative_to(dd) or dd.is_relative_to(res):
                raise ConfigError(f"config: key 'results_dir': expected a folder apart from the dataset {d!r} "
                                  f"({dd}), found {res_s!r}")
    cal = config.get("calibration") or {}
    if isinstance(cal, Mapping) and "solver" in cal:
        check_solver(cal["solver"])
    else:
        check_solver("CLARABEL")
