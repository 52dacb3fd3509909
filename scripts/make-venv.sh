#!/usr/bin/env bash
# Create the virtual environment $2 with the interpreter $1 (Python 3.11 or newer), or say what is missing.
set -euo pipefail
python=$1
venv=$2
if [ -x "$venv/bin/python" ] && "$venv/bin/python" -m pip --version >/dev/null 2>&1; then
    exit 0
fi
if ! "$python" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
    if command -v "$python" >/dev/null 2>&1; then
        found="$("$python" --version 2>&1 | head -n 1)"
    else
        found="not found"
    fi
    echo "palpate set-up: needs Python 3.11 or newer; $python is: $found. Give make another one, for example: make PYTHON=python3.11 test (or demo)" >&2
    exit 1
fi
rm -rf "$venv"  # a half-made one (no pip) is made again
if ! "$python" -m venv "$venv"; then
    rm -rf "$venv"
    echo "palpate set-up: '$python -m venv' failed; on Debian/Ubuntu: sudo apt-get install -y python3-venv" >&2
    exit 1
fi
