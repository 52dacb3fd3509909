"""`palpate view`: the exploration in the rerun viewer, live from the bus or from an MCAP log.

rerun-sdk is an optional extra (`pip install 'palpate[viewer]'`): nothing in palpate imports it at
module level. `rerun_log` maps messages to archetype log calls without rerun (pure, tested with a
fake logger), `sink` adapts those calls to a rerun recording, `sources` reads messages from an MCAP
log or from the running bus.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from palpate.errors import ViewerError

EXTRA_HINT = "the viewer extra is not installed: pip install 'palpate[viewer]'"


def require_rerun() -> ModuleType:
    """The `rerun` module, or ViewerError saying how to install it."""
    try:
        return importlib.import_module("rerun")
    except ModuleNotFoundError as exc:
        if exc.name == "rerun":
            raise ViewerError(EXTRA_HINT) from exc
        raise ViewerError(f"{EXTRA_HINT} (rerun is installed but incomplete: {exc})") from exc
    except ImportError as exc:
        raise ViewerError(f"{EXTRA_HINT} (importing rerun failed: {exc})") from exc
