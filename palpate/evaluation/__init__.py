"""Benchmarks that run whole node graphs many times: `palpate eval ...` and `palpate sweep ...`."""
