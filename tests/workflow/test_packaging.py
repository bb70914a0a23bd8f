"""Packaging: the hash-pinned lock satisfies pyproject's ranges, the version has one source, and the tested
environment is the locked one (docs/reproducibility.md)."""
import re
import tomllib
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

import selfsense

ROOT = Path(__file__).resolve().parents[2]


def _lock() -> dict[str, str]:
    text = (ROOT / "requirements.lock").read_text()
    pins = dict(re.findall(r"^([A-Za-z0-9_.\-]+)==([^\s\\;]+)", text, flags=re.M))
    assert text.count("--hash=sha256:") >= len(pins), "every pin carries hashes"
    return {canonicalize_name(k): v for k, v in pins.items()}


def _requirements() -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    reqs = list(project["dependencies"])
    for extra in ("slurm", "matlab", "dev"):
        reqs += project["optional-dependencies"][extra]
    return [Requirement(r) for r in reqs]


def test_every_dependency_and_extra_is_pinned_within_its_range_and_bounded_above():
    pins = _lock()
    for req in _requirements():
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} missing from requirements.lock"
        assert req.specifier.contains(pins[name]), f"{req.name}=={pins[name]} outside {req.specifier}"
        assert any(s.operator == "<" for s in req.specifier), f"{req.name} has no upper bound"


def test_one_version_source():
    try:
        installed = version("selfsense")
    except PackageNotFoundError:
        pytest.skip("selfsense is not installed (pip install --no-deps -e .)")
    assert installed == selfsense.__version__
    assert "version" not in tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert not re.search(r"^version:", (ROOT / "CITATION.cff").read_text(), flags=re.M)


def test_installed_environment_is_the_locked_one():
    """The suite runs in the environment of the README's commands: every locked core package at its pin."""
    pins = _lock()
    for name in ("numpy", "scipy", "pandas", "numba", "cvxpy", "snakemake"):
        assert version(name) == pins[name], f"{name} {version(name)} installed, {pins[name]} locked"
