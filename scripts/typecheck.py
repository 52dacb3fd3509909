"""Run mypy over the installed package layout: `palpate`, plus `nodes/` and `messages/` as mapped.

pyproject.toml installs `nodes/` as `palpate.nodes` and `messages/` as `palpate.messages` (package
mapping). The editable install resolves them with an import hook that mypy cannot follow, so this
script mirrors the mapping in `build/typecheck/` (links to the source files, outside the git tree)
and checks `-p palpate` there. Errors name paths relative to build/typecheck/: palpate/nodes/x.py is nodes/x.py,
palpate/messages/x.py is messages/x.py.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MIRROR = ROOT / "build" / "typecheck"


def build_mirror() -> None:
    """build/typecheck/<package path> -> the source directory of each mapped package."""
    package_dir: dict[str, str] = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-dir"
    ]
    shutil.rmtree(MIRROR, ignore_errors=True)
    for package, source in sorted(package_dir.items(), key=lambda item: item[0].count(".")):
        target = MIRROR.joinpath(*package.split("."))
        target.mkdir(parents=True, exist_ok=True)
        for child in (ROOT / source).iterdir():
            if child.name != "__pycache__" and not (target / child.name).exists():
                (target / child.name).symlink_to(child)


def main() -> int:
    build_mirror()
    config, cache = str(ROOT / "pyproject.toml"), str(ROOT / ".mypy_cache")
    command = [sys.executable, "-m", "mypy", "--config-file", config, "--cache-dir", cache, "-p", "palpate"]
    return subprocess.call(command, cwd=MIRROR)


if __name__ == "__main__":
    sys.exit(main())
