#!/usr/bin/env bash
# Create the virtual environment $2 with the interpreter $1 (Python 3.11 or newer), or say what is missing.
set -euo pipefail
python=$1
venv=$2
if [ -x "$venv/bin/python" ] && "$venv/bin/python" -m pip --version >/dev/null 2>&1; then
    exit 0
fi
if ! "$python" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
    found=$("$python" --version 2>&1 || echo "not found")
    echo "palpate set-up: needs Python 3.11 or newer; $python is: $found. Run: make PYTHON=python3.11 demo" >&2
    exit 1
fi
rm -rf "$venv"  # a half-made one (no pip) is made again
if ! "$python" -m venv "$venv"; then
    rm -rf "$venv"
    echo "palpate set-up: '$python -m venv' failed; on Debian/Ubuntu: sudo apt-get install -y python3-venv" >&2
    exit 1
fi
