"""`palpate keys`: generate CurveZMQ keys for cross-host links (the launch key `curve_keys`).

A key file is JSON with z85 text keys ``{"public", "secret", "server_public"}``. A node given the
file authenticates its publisher (a Curve server) with `public`/`secret`, and its subscriber (a Curve
client) expects every publisher it connects to to hold the secret key matching `server_public`.
`palpate keys -o graph.key` writes a graph key (server_public = public): give that one file to every
node of the graph. `--server-public KEY` writes a client key for a node whose peers use another key.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from palpate.argtypes import path_arg
from palpate.paths import why_not
from palpate.runtime.bus import is_z85_key, make_curve_keys

KEY_FIELDS = ("public", "secret", "server_public")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("keys", help="generate a CurveZMQ key file for the launch key `curve_keys`")
    p.add_argument("-o", "--output", type=path_arg, required=True, help="key file to write (JSON, mode 0600)")
    p.add_argument(
        "--server-public",
        metavar="Z85",
        help="public key of the publishers this node connects to (default: the new key's own public key)",
    )
    p.add_argument("--force", action="store_true", help="overwrite an existing key file")
    p.set_defaults(func=run_keys)


def write_keys(path: Path, keys: dict[str, str], *, force: bool = False) -> None:
    """Write `keys` as JSON readable only by the owner (it holds a secret key)."""
    flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if force else os.O_EXCL)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, flags, 0o600)
    with os.fdopen(fd, "w") as f:
        json.dump({k: keys[k] for k in KEY_FIELDS}, f, indent=2)
        f.write("\n")


def run_keys(args: argparse.Namespace) -> int:
    server_public = args.server_public
    if server_public is not None and not is_z85_key(server_public):
        print("palpate keys: --server-public must be a 40-character z85 public key", file=sys.stderr)
        return 2
    keys = make_curve_keys(server_public)
    try:
        write_keys(args.output, keys, force=args.force)
    except (OSError, RecursionError) as exc:  # (RecursionError: mkdir of a path of 1,000s of parts)
        if isinstance(exc, FileExistsError) and os.path.lexists(args.output):  # (not a file in the folder's way)
            print(f"palpate keys: {args.output} exists; pass --force to replace it", file=sys.stderr)
            return 2
        why = why_not(exc)
        print(f"palpate keys: cannot write {args.output}: {why}", file=sys.stderr)
        return 2
    print(f"wrote {args.output}; public key {keys['public']}")
    print(f"use it in a launch file as `curve_keys: {args.output}` on every node of the cross-host links")
    return 0
