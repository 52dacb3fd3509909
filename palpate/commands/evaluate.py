"""`palpate eval <name>` and `palpate sweep <name>`: benchmarks that run whole node graphs many times.

Each evaluation and sweep is a "module:function" that configures its sub-command's parser (adds its
arguments and sets ``func``); adding one is one line in EVALUATIONS or SWEEPS. Modules are imported
when the parser is built, so they must keep heavy imports inside their functions.
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable, Mapping

#: `palpate eval NAME` -> "module:function(parser)".
EVALUATIONS: dict[str, str] = {
    "explore": "palpate.evaluation.explore:configure",
    "slam": "palpate.evaluation.slam:configure",
    "rescore": "palpate.evaluation.rescore:configure",
}
#: `palpate sweep NAME` -> "module:function(parser)".
SWEEPS: dict[str, str] = {
    "explore": "palpate.evaluation.sweep_explore:configure",
    "slam": "palpate.evaluation.sweep_slam:configure",
}

HELP = {
    "eval": {
        "explore": "active tactile exploration (paper 002): the strategies (IGEF, GP-V, ...) on a folder of meshes",
        "slam": "Haptic SLAM (paper 000): known pose, dead reckoning and FastSLAM maps of the Rubik's cube",
        "rescore": "an explore evaluation's whole estimate rebuilt from its touches under other GPIS settings",
    },
    "sweep": {
        "explore": "exploration's speed-accuracy knobs (GP, mesh step, candidate step, time step, speed, noise)",
        "slam": "FastSLAM's particles K x grid resolution: map error against time per update",
    },
}


def _configurer(target: str) -> Callable[[argparse.ArgumentParser], None]:
    module, _, function = target.partition(":")
    configure: Callable[[argparse.ArgumentParser], None] = getattr(importlib.import_module(module), function)
    return configure


def _add_group(
    sub: argparse._SubParsersAction[argparse.ArgumentParser], command: str, help_text: str, table: Mapping[str, str]
) -> None:
    parser = sub.add_parser(command, help=help_text)
    group = parser.add_subparsers(dest=f"{command}_name", required=True, metavar="NAME")
    for name, target in table.items():
        _configurer(target)(group.add_parser(name, help=HELP[command].get(name, "")))


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    _add_group(sub, "eval", "run an evaluation: " + ", ".join(EVALUATIONS), EVALUATIONS)
    _add_group(sub, "sweep", "sweep parameters of an evaluation: " + ", ".join(SWEEPS), SWEEPS)
