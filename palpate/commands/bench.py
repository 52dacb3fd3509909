"""`palpate bench <name>`: benchmarks, each in its own module and run on demand.

To add a benchmark, add one line to BENCHMARKS: its name, the "module:function" that runs it (taking
the parsed arguments and returning an exit code) and a one-line help. Every benchmark gets --quick
and --json (with --json, the last line of output is one JSON object); a module may also define
`add_arguments(parser)` for options of its own. The modules are imported when the parser is built,
to collect those options: keep heavy imports (mujoco, open3d) inside their functions. A listed
module that does not exist yet is left out of the command.
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable
from typing import Any

#: Benchmark name -> ("module:function", help).
BENCHMARKS: dict[str, tuple[str, str]] = {
    "bus": ("palpate.bench.bus:main", "one-hop latency and throughput of the bus against raw pyzmq"),
    "sim": ("palpate.bench.sim:main", "simulation steps/s and real-time factor: bare mj_step, in-process, graph"),
    "contacts": ("palpate.bench.contacts:main", "exact-mesh contact accuracy (position, normal, phantom) on YCB"),
    "gpis": ("palpate.bench.gpis:main", "GPIS update + local surface ms against contacts and grid step"),
    "fuzz": ("palpate.bench.fuzz:main", "schema-valid extremes and malformed payloads into every node: crashes = 0"),
}


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("bench", help="run a benchmark (" + ", ".join(BENCHMARKS) + ")")
    benches = p.add_subparsers(dest="benchmark", required=True, metavar="BENCHMARK")
    for name, (target, text) in BENCHMARKS.items():
        module_name = target.partition(":")[0]
        try:
            module = _module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name == module_name:  # a benchmark not written yet
                continue
            raise
        b = benches.add_parser(name, help=text, description=text)
        b.add_argument("--quick", action="store_true", help="fewer iterations: well under a minute")
        b.add_argument("--json", action="store_true", help="end the output with one line of JSON")
        add_arguments = getattr(module, "add_arguments", None)
        if add_arguments is not None:
            add_arguments(b)
        b.set_defaults(func=_runner(target))


def _module(name: str) -> Any:
    return importlib.import_module(name)


def _runner(target: str) -> Callable[[argparse.Namespace], int]:
    module_name, _, function = target.partition(":")

    def run(args: argparse.Namespace) -> int:
        return int(getattr(_module(module_name), function)(args) or 0)

    return run
