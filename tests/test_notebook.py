"""docs/examples/first_steps.ipynb, the notebook a researcher opens first, executed cell by cell (so that it cannot
rot): every code cell runs in order in one namespace (the notebook's kernel, without Jupyter: nbformat reads it,
``exec`` runs it), in a temporary working directory; a failing cell is reported with its index and source."""
from __future__ import annotations

import os
import time
from pathlib import Path

import matplotlib
import nbformat
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "docs" / "examples" / "first_steps.ipynb"


def test_notebook_is_stored_without_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code, "the notebook has no code"
    for i, c in enumerate(code):
        assert not c.get("outputs") and c.get("execution_count") is None, f"code cell {i} holds outputs: clear them"
    text = "".join(c.source for c in nb.cells)
    assert "/work/" not in text and "/home/" not in text and "/root/" not in text, "a machine path in the notebook"


def test_notebook_runs_and_its_results_are_real(tmp_path, monkeypatch, capsys):
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("SELFSENSE_NOTEBOOK_WORKDIR", str(tmp_path / "work"))
    monkeypatch.setenv("SELFSENSE_REPO", str(ROOT))
    nb = nbformat.read(NOTEBOOK, as_version=4)
    ns: dict = {"__name__": "__notebook__"}
    t0 = time.perf_counter()
    for i, cell in enumerate(c for c in nb.cells if c.cell_type == "code"):
        src = cell.source
        try:
            exec(compile(src, f"<first_steps.ipynb code cell {i}>", "exec"), ns)
        except Exception as exc:  # noqa: BLE001
            pytest.fail(f"code cell {i} failed: {type(exc).__name__}: {exc}\n--- cell {i} ---\n{src}")
    wall = time.perf_counter() - t0
    with capsys.disabled():
        print(f"\n[notebook] docs/examples/first_steps.ipynb ran in {wall:.1f} s")
    # the pipeline ran and wrote Table 3 for both measurements
    t3 = ns["table3"].set_index("measurement")
    assert list(t3.index) == ["displacement", "force"] and (t3["percent_of_range"] > 0).all()
    # the fitted H beats the straight line on the user's record
    assert ns["rms_pi"] < 0.9 * ns["rms_line"]
    # the figures are for people: labelled axes with units
    for name in ("fig_estimate", "fig_h"):
        ax = ns[name].axes[0]
        assert "[" in ax.get_xlabel() and "[" in ax.get_ylabel(), (name, ax.get_xlabel(), ax.get_ylabel())
    # the stream ran the pipeline's own model over the whole log, and its error is the batch's within 3 points
    assert len(ns["dx_stream"]) == len(ns["est"]) and np.isfinite(ns["dx_stream"]).all()
    assert abs(ns["err_stream"] - ns["err_batch"]) < 3.0, (ns["err_stream"], ns["err_batch"])
    # nothing was written into the repository
    assert not (ROOT / "docs" / "examples" / "results").exists()
    plt.close("all")
    assert os.environ["SELFSENSE_NOTEBOOK_WORKDIR"] == str(tmp_path / "work")
