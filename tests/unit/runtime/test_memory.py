"""The allocator tuning that node processes apply (palpate.runtime.memory)."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

from palpate.runtime import memory

glibc_only = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt tuning needs glibc")

# Allocate eight 1 MB payloads, free them, again and again (as a node streaming big messages does);
# print the page faults per buffer. A fresh interpreter, so that the allocator starts untouched.
_CYCLES = """
import resource, sys
from palpate.runtime import memory
assert memory.keep_freed_buffers() is True
chunk = b"x" * (1 << 20)
def cycle():
    buffers = [b"".join([b"\\x92", chunk]) for _ in range(8)]
    del buffers
cycle()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    cycle()
print((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 160)
"""


@glibc_only
def test_freed_big_buffers_are_reused_without_page_faults() -> None:
    result = subprocess.run([sys.executable, "-c", _CYCLES], capture_output=True, text=True, timeout=60, check=True)
    faults_per_buffer = float(result.stdout)
    assert faults_per_buffer < 5, f"{faults_per_buffer} page faults per 1 MB buffer (256 pages) after tuning"


def test_returns_a_bool_everywhere() -> None:
    assert isinstance(memory.keep_freed_buffers(), bool)
