"""MuJoCo's C functions for compiled loops: their addresses in the library the Python bindings loaded,
and a numba intrinsic that calls one of them (``probe_kernels``, ``penalty_kernels``)."""

from __future__ import annotations

import ctypes
from functools import cache
from pathlib import Path
from typing import Any

from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic


@cache
def function_addresses(*names: str) -> tuple[int, ...] | None:
    """Addresses of the named functions in MuJoCo's shared library beside the bindings (the same code
    the bindings run), or None where the library or a function is not found."""
    import mujoco

    folder = Path(mujoco.__file__).resolve().parent
    libraries = sorted(folder.glob("libmujoco.so*")) + sorted(folder.glob("libmujoco*.dylib"))
    if not libraries:
        return None
    try:
        library = ctypes.CDLL(str(libraries[0]))
        addresses = [ctypes.cast(getattr(library, name), ctypes.c_void_p).value for name in names]
    except (OSError, AttributeError):
        return None
    if not all(addresses):
        return None
    return tuple(int(a) for a in addresses if a is not None)


def _call_void2_typer(typingctx: Any, function: Any, first: Any, second: Any) -> Any:
    """Call the C function ``void f(void *, void *)`` at address ``function`` with two addresses."""
    signature = types.void(types.intp, types.intp, types.intp)

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        pointer = ir.IntType(8).as_pointer()
        kind = ir.FunctionType(ir.VoidType(), [pointer, pointer])
        callee = builder.inttoptr(args[0], kind.as_pointer())
        builder.call(callee, [builder.inttoptr(args[1], pointer), builder.inttoptr(args[2], pointer)])
        return context.get_dummy_value()

    return signature, codegen


call_void2: Any = intrinsic(_call_void2_typer)
