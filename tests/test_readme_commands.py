"""The README starts with the two set-up commands, and they name an interpreter that any supported Python provides."""
from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_readme_starts_with_two_commands_for_any_supported_python():
    text = (ROOT / "README.md").read_text()
    block = re.search(r"```bash\n(.*?)```", text, re.S)
    assert block and text.index("```bash") < 40, "the README must open with the command block"
    cmds = [c for c in block.group(1).splitlines() if c.strip()]
    assert len(cmds) == 2
    for c in cmds:
        # `python3` exists with 3.11, 3.12 and 3.13 alike; a pinned minor version would stop on the other two
        assert c.startswith("python3 -m venv .venv && "), c
        assert "pip install -r requirements.lock" in c
    assert cmds[0].endswith("selfsense run --cores 2")
    assert cmds[1].endswith("python -m pytest -n 2 --dist loadfile -q")


def test_running_interpreter_is_supported():
    assert (3, 11) <= sys.version_info[:2] <= (3, 13), sys.version
