"""Benchmarks run by `palpate bench <name>` (see palpate/commands/bench.py for the list)."""
