"""The ``selfsense`` command line: described subcommands and options, --version, one-line errors, and
``selfsense run`` passing options to Snakemake untouched with configs layered on the packaged defaults."""
from __future__ import annotations

import argparse
import importlib
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import yaml

from selfsense import cli
from selfsense.cli import run as pipeline_cli

ROOT = Path(__file__).resolve().parents[1]


def test_version_and_usage(capsys):
    assert cli.main(["--version"]) == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith("selfsense ") and out.split()[1][0].isdigit()
    assert cli.main(["--help"]) == 0
    usage = capsys.readouterr().out
    for name, (mod, _, desc) in cli.SUBCOMMANDS.items():
        assert f"  {name}" in usage and desc in usage
        assert mod not in usage, "usage must describe commands, not list module paths"


def _collect_parsers(monkeypatch) -> list[argparse.ArgumentParser]:
    made: list[argparse.ArgumentParser] = []
    orig = argparse.ArgumentParser.__init__

    def init(self, *a, **kw):
        orig(self, *a, **kw)
        made.append(self)

    monkeypatch.setattr(argparse.ArgumentParser, "__init__", init)
    return made


@pytest.mark.parametrize("argv", [
    ["init", "--help"], ["validate", "--help"], ["simulate", "--help"], ["estimate", "--help"],
    ["export", "--help"], ["export-c", "--help"], ["stream", "--help"], ["gap", "diagnose", "--help"],
    ["gap", "blind", "--help"],
    ["gap", "blind-calibrate", "--help"],
    ["ri", "compare-slac", "--help"], ["ri", "validate-table", "--help"], ["fit-external", "--help"],
])
def test_every_option_has_help_and_no_abbreviation(argv, monkeypatch, capsys):
    parsers = _collect_parsers(monkeypatch)
    with pytest.raises(SystemExit) as e:
        cli.main(argv)
    assert e.value.code == 0
    assert parsers, "the subcommand built no argparse parser"
    for p in parsers:
        assert p.allow_abbrev is False, f"{p.prog}: argparse abbreviations must be off (--config != --configfile)"
        for act in p._actions:
            if isinstance(act, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            assert act.help, f"{p.prog}: option {act.option_strings or act.dest} has no help text"
    assert capsys.readouterr().out.strip()


def test_run_help_describes_pass_through(capsys):
    assert cli.main(["run", "--help"]) == 0
    out = capsys.readouterr().out
    assert "handed to Snakemake unchanged" in out and "--config" in out


def test_unknown_command_and_user_error_are_one_line(tmp_path, capsys):
    assert cli.main(["nosuchcommand"]) == 2
    assert "unknown command 'nosuchcommand'" in capsys.readouterr().err
    # an estimate on a missing model file: one line, exit 2, no traceback
    (tmp_path / "ds").mkdir()
    rc = cli.main(["estimate", "--model", str(tmp_path / "none.json"), "--dataset", str(tmp_path / "ds"),
                   "--log", str(tmp_path / "x.parquet"), "--out", str(tmp_path / "out" / "o.parquet")])
    err = capsys.readouterr().err
    assert rc == 2
    assert "Traceback" not in err and err.count("\n") == 1 and err.startswith("selfsense estimate: error: ")
    assert "rig.yaml" in err


def test_contract_error_one_line_per_problem(tmp_path, capsys):
    from selfsense.io.errors import ContractError, Problem

    def boom(argv):
        raise ContractError([Problem("trials.csv", "role", 3, "'calibration' or 'validation'", "calib"),
                             Problem("rig.yaml", "sample_rate_hz", None, "a number > 0", -1)])

    cli.SUBCOMMANDS["_boom"] = (__name__, "_boom_target", "test")
    globals()["_boom_target"] = boom
    try:
        assert cli.main(["_boom"]) == 2
    finally:
        del cli.SUBCOMMANDS["_boom"]
    lines = capsys.readouterr().err.splitlines()
    assert lines == ["selfsense _boom: error: trials.csv: column 'role', row 3: expected 'calibration' or "
                     "'validation', found 'calib'",
                     "selfsense _boom: error: rig.yaml: key 'sample_rate_hz': expected a number > 0, found -1"]


# ------------------------------------------------------------------------------------------- selfsense run


def test_layered_config_partial_file_and_overrides(tmp_path):
    (tmp_path / "mine.yaml").write_text("datasets: [mine]\ncalibration: {h_model: ri}\n")
    argv = ["--configfile", str(tmp_path / "mine.yaml"), "--config", "on_bad_trial=skip", "results_dir=out",
            "--cores", "1"]
    cfg = pipeline_cli.layered_config(argv, tmp_path)
    default = pipeline_cli.default_config()
    assert cfg["datasets"] == ["mine"]
    assert cfg["on_bad_trial"] == "skip" and cfg["results_dir"] == "out"
    # a partial section merges into the defaults instead of replacing them
    assert cfg["calibration"]["h_model"] == "ri"
    assert cfg["calibration"]["n_play"] == default["calibration"]["n_play"]
    assert cfg["estimation"] == default["estimation"]


def test_run_missing_dataset_is_one_line_exit_2(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.yaml").write_text("datasets: [absent]\n")
    assert cli.main(["run", "--configfile", "mine.yaml", "-n"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "absent" in err and str(tmp_path) in err
    assert cli.main(["run", "--configfile", "missing.yaml"]) == 2
    assert "--configfile missing.yaml: no such file" in capsys.readouterr().err


def test_run_passes_options_untouched(tmp_path, monkeypatch, capsys):
    """`--config on_bad_trial=skip` must reach Snakemake as a config override, not as --configfile (argparse
    abbreviation), the caller's directory is the working directory, and the packaged Snakefile is used."""
    calls = []
    monkeypatch.setattr(pipeline_cli, "_call_snakemake",
                        lambda args, cwd: calls.append(([sys.executable, "-m", "snakemake", *args], cwd)) or 0)
    _bad_copy(tmp_path, "mine")  # a valid copy of the sample dataset (rig.yaml and trials.csv are checked first)
    (tmp_path / "mine.yaml").write_text("datasets: [mine]\n")
    monkeypatch.chdir(tmp_path)
    assert cli.main(["run", "--configfile", "mine.yaml", "--config", "on_bad_trial=skip", "--dry-run"]) == 0
    (cmd, cwd), = calls
    i = cmd.index("snakemake")
    args = cmd[i + 1:]
    assert args[-5:] == ["--configfile", "mine.yaml", "--config", "on_bad_trial=skip", "--dry-run"]
    assert args[args.index("--directory") + 1] == str(tmp_path)
    assert Path(args[args.index("--snakefile") + 1]) == pipeline_cli.workflow_dir() / "Snakefile"
    assert args[args.index("--cores") + 1] == "2"
    assert Path(cwd) == tmp_path
    calls.clear()
    # a config.yaml in the working directory is layered automatically; --cores given -> not added
    (tmp_path / "config.yaml").write_text("datasets: [mine]\n")
    assert cli.main(["run", "-c", "1", "-n"]) == 0
    args = calls[0][0]
    assert "--cores" not in args and f"--configfile={tmp_path / 'config.yaml'}" in args
    # a target first: Snakemake's own parser must see it as a target, not as a second config file
    from snakemake.cli import get_argument_parser

    calls.clear()
    assert cli.main(["run", "matlab", "-n"]) == 0
    parsed = get_argument_parser().parse_args(calls[0][0][calls[0][0].index("snakemake") + 1:])
    assert parsed.targets == ["matlab"] and [str(p) for p in parsed.configfile] == [str(tmp_path / "config.yaml")]
    # a target after an option of one value is a target, not a second value (here: not the working directory)
    assert pipeline_cli._option_values(["--directory", "sub", "matlab"], ("--directory", "-d"), many=False) == ["sub"]
    calls.clear()
    assert cli.main(["run", "--directory", ".", "matlab", "-n"]) == 0
    assert get_argument_parser().parse_args(calls[0][0][calls[0][0].index("snakemake") + 1:]).targets == ["matlab"]


@pytest.mark.parametrize("args,env,local", [
    (["--cores", "2"], {}, True),
    (["--executor", "local"], {}, True),
    (["-n"], {}, True),
    (["--executor", "slurm"], {}, False),
    (["--executor=cluster-generic"], {}, False),
    (["-e", "slurm"], {}, False),
    (["--profile", "workflow/profiles/slurm"], {}, False),
    (["--workflow-profile=p"], {}, False),
    (["--cores", "2"], {"SNAKEMAKE_PROFILE": "slurm"}, False),
])
def test_only_a_local_run_skips_the_slurm_plugin(args, env, local):
    """A run on this machine starts Snakemake without the SLURM executor plugins (their start-up probe waits for an
    unreachable controller); an executor other than a local one, or a profile that may name one, keeps them."""
    cmd = pipeline_cli.snakemake_command(args, env)
    assert cmd[:3] == [sys.executable, "-m", "selfsense.cli._local_snakemake" if local else "snakemake"]
    assert cmd[3:] == args


def test_the_local_launcher_hides_only_the_slurm_plugins():
    """The local launcher removes the SLURM executor plugins from Snakemake's plugin discovery and nothing else; the
    launcher's Snakemake lists the local executors and not slurm."""
    from types import SimpleNamespace

    from selfsense.cli._local_snakemake import without_skipped

    mods = [SimpleNamespace(name=n) for n in ("snakemake_executor_plugin_slurm", "snakemake_executor_plugin_slurm_"
                                             "jobstep", "snakemake_executor_plugin_cluster_generic", "numpy")]
    assert [m.name for m in without_skipped(mods)] == ["snakemake_executor_plugin_cluster_generic", "numpy"]
    code = ("from selfsense.cli._local_snakemake import hide_skipped_plugins; hide_skipped_plugins(); "
            "from snakemake_interface_executor_plugins.registry import ExecutorPluginRegistry as R; "
            "print(sorted(R().plugins))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    names = out.stdout
    assert "slurm" not in names and "cluster-generic" in names


def test_the_local_launcher_returns_snakemakes_exit_status(monkeypatch):
    """Snakemake's command line ends with sys.exit; the launcher's main returns that status (the program then ends
    its process with it, selfsense.process.end_now)."""
    import snakemake.cli

    from selfsense.cli import _local_snakemake

    seen = []

    def fake_snakemake(argv):
        seen.append(argv)
        sys.exit(3)

    monkeypatch.setattr(snakemake.cli, "main", fake_snakemake)
    assert _local_snakemake.main(["--cores", "1"]) == 3
    assert seen == [["--cores", "1"]]
    monkeypatch.setattr(snakemake.cli, "main", lambda argv: sys.exit(None))
    assert _local_snakemake.main([]) == 0


def test_end_now_runs_the_exit_handlers_and_flushes_without_waiting_for_threads(tmp_path):
    """A process ended by end_now: its exit status, its buffered output and what its exit handlers write are there
    as after a normal exit; a non-daemon timer thread still waiting (as Snakemake's scheduler leaves one) is not
    waited for, and its action never runs."""
    code = (
        "import atexit, sys, threading\n"
        "from pathlib import Path\n"
        "from selfsense.process import end_now\n"
        f"out = Path({str(tmp_path)!r})\n"
        "atexit.register(lambda: (out / 'handler').write_text('ran'))\n"
        "threading.Timer(600, lambda: (out / 'timer').write_text('fired')).start()\n"
        "sys.stdout.write('buffered, no newline')\n"
        "end_now(3)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 3, proc.stderr[-2000:]
    assert proc.stdout == "buffered, no newline"
    assert (tmp_path / "handler").read_text() == "ran"
    assert not (tmp_path / "timer").exists()


def test_workflow_ships_with_the_package():
    d = pipeline_cli.workflow_dir()
    for rel in ("Snakefile", "config.yaml", "workflow/rules/pipeline.smk", "workflow/schemas/config.schema.yaml",
                "workflow/scripts/figures.py", "profiles/default/config.yaml"):
        assert (d / rel).is_file(), rel
    assert (d / "Snakefile").resolve() == (ROOT / "Snakefile").resolve(), "the shipped workflow must be the repo's"


@pytest.mark.slow
def test_wheel_runs_outside_a_checkout(tmp_path):
    """Build the wheel, unpack it away from the checkout and dry-run the pipeline from a directory holding only a
    partial config and a dataset: the Snakefile, rules, scripts, schema and default config come from the wheel."""
    whl_dir = tmp_path / "wheel"
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(whl_dir), str(ROOT)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    whl, = whl_dir.glob("selfsense-*.whl")
    site = tmp_path / "site"
    zipfile.ZipFile(whl).extractall(site)
    names = set(zipfile.ZipFile(whl).namelist())
    for rel in ("Snakefile", "config.yaml", "workflow/rules/pipeline.smk", "workflow/rules/common.smk",
                "workflow/schemas/config.schema.yaml", "workflow/scripts/figures.py",
                "workflow/report/figure.rst", "profiles/default/config.yaml"):
        assert f"selfsense/_workflow/{rel}" in names, rel
    user = tmp_path / "user"
    shutil.copytree(ROOT / "data" / "raw" / "sample", user / "data" / "raw" / "sample")
    (user / "mine.yaml").write_text("datasets: [sample]\n")
    env = dict(os.environ, PYTHONPATH=str(site))
    proc = subprocess.run([sys.executable, "-m", "selfsense", "run", "--configfile", "mine.yaml", "--dry-run"],
                          cwd=user, env=env, capture_output=True, text=True, timeout=600)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert str(site / "selfsense" / "_workflow" / "Snakefile") in out
    assert "report" in out and "ingest" in out
    assert not (user / "results").exists()


def test_init_writes_a_template_that_names_the_contract(tmp_path, capsys):
    from selfsense.io.trials import ALLOWED, TRIAL_COLUMNS

    d = tmp_path / "myrig"
    assert cli.main(["init", str(d)]) == 0
    rig = yaml.safe_load((d / "rig.yaml").read_text())
    assert rig["dataset"] == "myrig"
    header = (d / "trials.csv").read_text().splitlines()[0].split(",")
    assert tuple(header) == TRIAL_COLUMNS
    readme = (d / "README.txt").read_text()
    for col, values in ALLOWED.items():
        assert " | ".join(values) in readme, col
    # rig.yaml passes the rig checks; trials.csv only lacks the logs
    from selfsense.io import validate_dataset

    msgs = [str(p) for p in validate_dataset(d)]
    assert msgs and all("rig.yaml" not in m for m in msgs)
    assert any("cal_free.csv" in m for m in msgs)
    # never overwrites without --force
    assert cli.main(["init", str(d)]) == 2
    assert "already exist" in capsys.readouterr().err
    assert cli.main(["init", str(d), "--force"]) == 0


def _bad_copy(tmp_path: Path, name: str) -> Path:
    d = tmp_path / "data" / "raw" / name
    shutil.copytree(ROOT / "data" / "raw" / "sample", d)
    (d / "rig.yaml").write_text((d / "rig.yaml").read_text().replace("dataset: sample", f"dataset: {name}"))
    return d


def test_run_bad_dataset_no_traceback(tmp_path):
    """Bad input found before Snakemake (trials.csv) and by the validate rule (a log): one line per problem, exit 2,
    no traceback anywhere in the output."""
    d = _bad_copy(tmp_path, "badtrials")
    t = d / "trials.csv"
    t.write_text(t.read_text().replace(",calibration,free,", ",calib,free,", 1))
    env = dict(os.environ, MPLBACKEND="Agg")
    proc = subprocess.run([sys.executable, "-m", "selfsense", "run", "--config", "datasets=[badtrials]"],
                          cwd=tmp_path, capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stdout + proc.stderr
    assert proc.stderr.strip().splitlines() == [
        f"selfsense run: error: {d}/trials.csv: column 'role', row 1: expected 'calibration' or 'validation' "
        "(did you mean 'calibration'?), found 'calib'"]
    import pandas as pd

    d = _bad_copy(tmp_path, "badlog")
    log = d / "cal_free.parquet"
    df = pd.read_parquet(log)
    df["u_cmd"] = df["u_cmd"] * 1000.0  # mV logged as V
    df.to_parquet(log, index=False)
    proc = subprocess.run([sys.executable, "-m", "selfsense", "run", "--config", "datasets=[badlog]"],
                          cwd=tmp_path, capture_output=True, text=True, env=env, timeout=600)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2, out[-3000:]
    assert "Traceback" not in out
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("selfsense run: error: badlog/logs/validate.log: cal_free.parquet: column 'u_cmd'")
    assert "mV logged as V?" in last


@pytest.mark.parametrize("argv, code", [
    (["validate", "{d}"], 1),
    (["gap", "diagnose", "{d}", "--out", "{tmp}/gapout", "--no-figures"], 2),
    (["estimate", "--model", "{tmp}/m.json", "--dataset", "{d}", "--log", "{d}/cal_free.parquet", "--out",
      "{tmp}/o.parquet"], 2),
    (["export", "{tmp}/results", "{d}", "--out", "{tmp}/exp"], 2),
    (["init", "{d}"], 2),
])
def test_subcommands_on_a_bad_dataset_print_no_traceback(tmp_path, argv, code):
    d = _bad_copy(tmp_path, "bad")
    (d / "rig.yaml").write_text((d / "rig.yaml").read_text().replace("shunt_resistance_ohm: 1000.0",
                                                                     "shunt_resistance_ohm: 0.0"))
    args = [a.format(d=d, tmp=tmp_path) for a in argv]
    proc = subprocess.run([sys.executable, "-m", "selfsense", *args], cwd=tmp_path, capture_output=True, text=True,
                          env=dict(os.environ, MPLBACKEND="Agg"), timeout=600)
    out = proc.stdout + proc.stderr
    assert proc.returncode == code, out[-2000:]
    assert "Traceback" not in out and 'File "' not in out
    if code == 2:
        assert all(ln.startswith(f"selfsense {args[0]}") for ln in proc.stderr.strip().splitlines()), proc.stderr
