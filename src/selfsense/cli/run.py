"""``selfsense run``: run the selfsense Snakemake pipeline in the current directory and print each report's path.

usage: selfsense run [SNAKEMAKE OPTIONS ...] [TARGETS ...]

Every option is handed to Snakemake unchanged (``snakemake --help`` lists them), for example
``--config on_bad_trial=skip``, ``--configfile mine.yaml``, ``--dry-run``, ``--profile workflow/profiles/slurm``.
``selfsense run`` only adds what is missing:

* ``--snakefile``: the workflow shipped with the package (Snakefile, rules, scripts, schema and default config),
  so it works from any directory, inside a checkout or not;
* ``--directory``: the current directory, so ``raw_dir`` / ``results_dir`` and every relative path of the
  config resolve from where you are (``data/raw/<dataset>`` and ``results/<dataset>`` by default);
* ``--cores 2`` unless ``--cores`` / ``--jobs`` / ``--profile`` / ``--executor`` is given;
* ``--configfile=config.yaml`` if the working directory holds a ``config.yaml`` and none is given (the ``=``
  form, so that targets may come first: ``selfsense run matlab``).

Configuration is layered: the packaged defaults (``selfsense run --print-config``), then each ``--configfile`` in
order (a partial file, e.g. only ``datasets: [mine]``, is enough), then ``--config key=value`` overrides.
The last lines printed are the paths of the HTML reports, one per dataset. Before Snakemake starts, the layered
configuration and every dataset's rig.yaml and trials.csv are checked; bad input there, or found by a rule (e.g.
a DAQ log that breaks the data contract), ends the output with one line per problem and exit code 2 (the rule's
traceback stays in its log). Otherwise the exit code is Snakemake's.
"""
from __future__ import annotations

import copy
import os
import signal
import subprocess
import sys
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

__all__ = ["main", "workflow_dir", "default_config", "layered_config"]

_CORES_FLAGS = ("--cores", "-c", "--jobs", "-j", "--profile", "--executor", "-e", "--workflow-profile")


def workflow_dir() -> Path:
    """Folder holding the shipped ``Snakefile``, ``config.yaml`` and ``workflow/`` (rules, scripts, schemas).

    In a checkout (editable install) these are the repository's own files (``src/selfsense/_workflow`` links to
    them); in an installed wheel they are package data of the same name."""
    d = Path(str(resources.files("selfsense") / "_workflow"))
    if not (d / "Snakefile").exists():  # pragma: no cover - broken installation
        raise FileNotFoundError(f"the selfsense workflow is missing from the installation ({d}/Snakefile)")
    return d


def default_config() -> dict:
    """The packaged default configuration (``config.yaml`` beside the shipped Snakefile)."""
    return yaml.safe_load((workflow_dir() / "config.yaml").read_text()) or {}


def _deep_update(base: dict, new: dict) -> dict:
    """Recursive dict merge with Snakemake's semantics (``snakemake.utils.update_config``): dicts merge, anything
    else (lists included) is replaced."""
    for k, v in (new or {}).items():
        if isinstance(v, dict) and isinstance(base.get(k), dict):
            _deep_update(base[k], v)
        else:
            base[k] = copy.deepcopy(v)
    return base


def _parse_value(v: str) -> Any:
    """A ``--config`` value as Snakemake reads it (``snakemake.cli.parse_config``): an int, else a float, else
    ``True`` / ``False``, else YAML read with the base loader (lists and mappings of strings), else the string;
    empty: None. The same types as Snakemake's, so that the schema check below refuses what Snakemake would, no more."""
    if v == "":
        return None

    def boolean(x: str) -> bool:
        if x in ("True", "False"):
            return x == "True"
        raise ValueError(x)

    for parse in (int, float, boolean, lambda x: yaml.load(x, Loader=yaml.BaseLoader)):  # noqa: S506 (BaseLoader)
        try:
            out = parse(v)
        except (ValueError, yaml.YAMLError):
            continue
        if out is not None and not callable(out):
            return out
    return v


def _option_values(argv: list[str], names: tuple[str, ...], many: bool = True) -> list[str]:
    """Values of an option that takes one or more values (``--configfile a b``, ``--configfile=a``); with ``many``
    False, of an option that takes one (``--directory sub matlab``: ``sub``, the target after it is not a value)."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        a = argv[i]
        hit = next((n for n in names if a == n or a.startswith(n + "=")), None)
        if hit is None:
            i += 1
            continue
        if a.startswith(hit + "="):
            out.append(a.split("=", 1)[1])
            i += 1
            continue
        i += 1
        while i < len(argv) and not argv[i].startswith("-"):
            out.append(argv[i])
            i += 1
            if not many:
                break
    return out


def _has_option(argv: list[str], names: tuple[str, ...]) -> bool:
    return any(a == n or a.startswith(n + "=") or (len(n) == 2 and a.startswith(n) and not a.startswith("--"))
               for a in argv for n in names)


def layered_config(argv: list[str], workdir: Path) -> dict:
    """The configuration Snakemake will see: packaged defaults <- each ``--configfile`` <- ``--config k=v``."""
    cfg = default_config()
    for f in _option_values(argv, ("--configfile", "--configfiles")):
        p = Path(f)
        data = yaml.safe_load(p.read_text()) if p.exists() else None
        if data is not None and not isinstance(data, dict):
            raise ValueError(f"{f}: expected a YAML mapping of configuration keys, found {type(data).__name__}")
        _deep_update(cfg, data or {})
    overrides: dict = {}
    for kv in _option_values(argv, ("--config", "-C")):
        if "=" not in kv:
            raise ValueError(f"--config {kv!r}: expected KEY=VALUE")
        k, v = kv.split("=", 1)
        overrides[k] = _parse_value(v)
    return _deep_update(cfg, overrides)


def _help() -> str:
    return __doc__.strip().replace("``", "") + "\n"


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ("-h", "--help"):
        print(_help())
        return 0
    if argv and argv[0] == "--print-config":
        print(yaml.safe_dump(default_config(), sort_keys=False), end="")
        return 0
    cwd = Path.cwd()
    wd_opt = _option_values(argv, ("--directory", "-d"), many=False)
    workdir = (cwd / wd_opt[-1]).resolve() if wd_opt else cwd
    extra: list[str] = []
    if not _has_option(argv, ("--snakefile", "-s")):
        extra += ["--snakefile", str(workflow_dir() / "Snakefile")]
    if not wd_opt:
        extra += ["--directory", str(workdir)]
    if not _has_option(argv, _CORES_FLAGS):
        extra += ["--cores", "2"]
    if not _has_option(argv, ("--configfile", "--configfiles")) and (workdir / "config.yaml").is_file():
        # the "=" form: one value, so a target the user gives first (``selfsense run matlab``) stays a target
        # (after ``--configfile PATH`` Snakemake would read every following word as another config file)
        extra += [f"--configfile={workdir / 'config.yaml'}"]
    for f in _option_values(argv, ("--configfile", "--configfiles")):
        if not Path(f).is_file():
            hint = ("; Snakemake reads every word after --configfile as a config file, so put targets first: "
                    f"selfsense run {f} --configfile ...") if not f.endswith((".yaml", ".yml", ".json")) else ""
            print(f"selfsense run: error: --configfile {f}: no such file (relative paths start at {cwd}){hint}",
                  file=sys.stderr)
            return 2
    cmd_args = extra + argv
    try:
        cfg = layered_config(cmd_args, workdir)
    except (ValueError, OSError, yaml.YAMLError) as exc:
        print(f"selfsense run: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    from selfsense.io.config import schema_problems

    # the schema Snakemake checks first, here with one line per problem (Snakemake's error prints the whole schema)
    schema = yaml.safe_load((workflow_dir() / "workflow" / "schemas" / "config.schema.yaml").read_text())
    wrong = schema_problems(cfg, schema)
    if wrong:
        for line in wrong:
            print(f"selfsense run: error: {line}", file=sys.stderr)
        return 2
    raw = workdir / str(cfg.get("raw_dir", "data/raw"))
    datasets = [str(d) for d in (cfg.get("datasets") or [])]
    missing = [d for d in datasets if not (raw / d).is_dir()]
    if missing:
        print(f"selfsense run: error: dataset folder(s) {', '.join(str(raw / d) for d in missing)} not found "
              f"(config 'datasets' {datasets} under raw_dir '{cfg.get('raw_dir', 'data/raw')}', relative to "
              f"{workdir}); create one with 'selfsense init' or 'selfsense simulate', or set --config "
              f"raw_dir=... datasets=[...]", file=sys.stderr)
        return 2
    from selfsense.io.config import ConfigError, check_config
    from selfsense.io.outputs import OutputError, output_lock

    try:  # before Snakemake parses anything: YAML aliases, results_dir apart from raw_dir, solver installed
        check_config(cfg, _option_values(cmd_args, ("--configfile", "--configfiles")), workdir=workdir)
    except ConfigError as exc:
        print(f"selfsense run: error: {exc}", file=sys.stderr)
        return 2
    # rig.yaml and trials.csv of every dataset before Snakemake builds its DAG from them (else a bad trials.csv
    # surfaces as Snakemake's InputFunctionException with a traceback); the logs are checked by the validate rule
    from selfsense.io import check_rig, check_trials

    bad = []
    for d in datasets:
        bad += [f"{raw / d}/{p}" for p in check_rig(raw / d)[1] + check_trials(raw / d)[1]]
    if bad:
        for line in bad:
            print(f"selfsense run: error: {' '.join(line.split())}", file=sys.stderr)
        return 2
    import time

    started = time.time()
    try:
        # one `selfsense run` per directory: a second one would see the first one's outputs as "incomplete" and
        # Snakemake would advise --rerun-incomplete, which is wrong while the first run is alive
        with output_lock(workdir / ".snakemake" / "selfsense-run", what="selfsense run in"):
            # holding this lock, no other selfsense run works here: Snakemake's own locks and incomplete markers
            # are what an interrupted run (Ctrl-C, a kill) left behind, so they are cleared and what was incomplete
            # is rerun (a plain `snakemake` started by hand in the same folder is not covered by this lock)
            stale = _clear_stale_locks(workdir)
            args = list(cmd_args)
            if not _has_option(args, ("--rerun-incomplete", "--ri", "--unlock")):
                args.insert(0, "--rerun-incomplete")  # before the caller's options, which reach Snakemake as given
            if stale:
                print(f"selfsense run: cleared {stale} stale Snakemake lock(s) of an interrupted run; incomplete "
                      "outputs are made again", file=sys.stderr)
            rc = _call_snakemake(args, cwd)
    except OutputError:
        print(f"selfsense run: error: another selfsense run is working in {workdir}; wait for it to finish "
              "(do not use --rerun-incomplete or --unlock while it runs)", file=sys.stderr)
        return 2
    if rc != 0:
        errors = _rule_errors(workdir / str(cfg.get("results_dir", "results")), datasets, started)
        for line in errors:
            print(f"selfsense run: error: {line}", file=sys.stderr)
        return 2 if errors else rc  # 2: bad input found by a rule (its message above), else Snakemake's code
    if any(a in ("-n", "--dry-run", "--dryrun") for a in argv):
        return 0
    results = workdir / str(cfg.get("results_dir", "results"))
    for d in datasets:
        report = results / d / "report.html"
        if report.exists():
            shown = report.relative_to(cwd) if report.is_relative_to(cwd) else report
            print(f"report: {shown}")
    return 0


def _clear_stale_locks(workdir: Path) -> int:
    """Remove Snakemake's lock files under ``workdir/.snakemake/locks`` (call only under the selfsense run lock)."""
    d = workdir / ".snakemake" / "locks"
    n = 0
    if d.is_dir():
        for f in d.iterdir():
            if f.is_file():
                f.unlink()
                n += 1
    return n


#: executors that run the jobs on this machine
LOCAL_EXECUTORS = ("local", "dryrun", "touch")


def runs_locally(args: list[str], env: dict | None = None) -> bool:
    """Whether Snakemake will run the jobs on this machine: no executor other than a local one, no profile (a profile
    may name any executor) and no ``SNAKEMAKE_PROFILE`` in the environment."""
    env = os.environ if env is None else env
    if _has_option(args, ("--profile", "--workflow-profile")) or env.get("SNAKEMAKE_PROFILE"):
        return False
    return all(v in LOCAL_EXECUTORS for v in _option_values(args, ("--executor", "-e"), many=False))


def snakemake_command(args: list[str], env: dict | None = None) -> list[str]:
    """The Snakemake command line of ``selfsense run``: a local run starts it without the SLURM executor plugins'
    start-up probe (:mod:`selfsense.cli._local_snakemake`), any other run as ``python -m snakemake``."""
    mod = "selfsense.cli._local_snakemake" if runs_locally(args, env) else "snakemake"
    return [sys.executable, "-m", mod, *args]


def _call_snakemake(args: list[str], cwd: Path) -> int:
    """Run Snakemake and wait for it, also on Ctrl-C: the interrupt reaches the child through the terminal's process
    group, and the parent waits until Snakemake has stopped its jobs and released its locks (a second Ctrl-C is
    passed on as a terminate)."""
    proc = subprocess.Popen(snakemake_command(args), cwd=cwd)
    while True:
        try:
            return proc.wait()
        except KeyboardInterrupt:
            try:
                proc.send_signal(signal.SIGINT)
                proc.wait(timeout=60)
            except (KeyboardInterrupt, subprocess.TimeoutExpired):
                proc.terminate()
                proc.wait()
            raise KeyboardInterrupt from None


def _rule_errors(results: Path, datasets: list[str], since: float, limit: int = 20) -> list[str]:
    """The ``ERROR:`` lines that failed rules of this run wrote to their logs (``selfsense.stages.logged``), so the
    cause ends the output as one line per problem, after Snakemake's own report."""
    out: list[str] = []
    for d in datasets:
        for log in sorted((results / d / "logs").rglob("*.log")):
            try:
                if log.stat().st_mtime < since:
                    continue
                lines = log.read_text(errors="replace").splitlines()
            except OSError:
                continue
            for i, ln in enumerate(lines):
                if ln.startswith("ERROR: "):
                    msg = ln[len("ERROR: "):].strip()
                    # a ContractError lists its problems on the following lines
                    more = []
                    for x in lines[i + 1:i + 40]:
                        if x.startswith("Traceback"):
                            break
                        if x.strip():
                            more.append(x.strip())
                    rel = log.relative_to(results)
                    out += [f"{rel}: {' '.join(x.split())}" for x in ([msg] + more if "contract problem" in msg
                                                                      else [msg])]
                    break
    return out[:limit]


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
