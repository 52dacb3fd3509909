"""The set-up scripts' own errors (scripts/make-venv.sh): they say what is missing and how to go on."""

from __future__ import annotations

import subprocess
from pathlib import Path

from palpate.paths import REPO_ROOT


def test_a_missing_interpreter_is_named_without_the_shells_error(tmp_path: Path) -> None:
    """An outside walkthrough: the message held bash's own "command not found" line and always said demo."""
    done = subprocess.run(
        ["bash", str(REPO_ROOT / "scripts" / "make-venv.sh"), "no-such-python3", str(tmp_path / "venv")],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr == (
        "palpate set-up: needs Python 3.11 or newer; no-such-python3 is: not found. Give make another one, "
        "for example: make PYTHON=python3.11 test (or demo)\n"
    )
    assert not (tmp_path / "venv").exists()
