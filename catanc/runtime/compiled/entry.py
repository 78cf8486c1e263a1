"""The compiled walk's machine code, linked into the enforcer and called without numba (issue 31's start-up).

numba compiles the walk (:mod:`catanc.runtime.compiled.walk`) with one C entry point around it
(:mod:`catanc.runtime.compiled.build`) into an object file, once per machine; ``catanc run`` links
that file into its own process with llvmlite (the code generator numba is built on, installed with
it from wheels) and calls the entry through ctypes, which lets go of the interpreter lock for the
call.  Loading it costs ~0.03 s of CPU, where importing numba and loading its cache of the same
code cost ~0.6 s.

The entry takes the walk as a *descriptor*: for each field of :class:`Walk`, in order, its data's
address and then its shape (each array is C-contiguous, so no strides).  The object file was
compiled for one layout (each field's dtype and dimensions): :func:`describe` refuses a walk of
another with ``TypeError``, as numba's dispatcher would.
"""

from __future__ import annotations

import ctypes
import os

import numpy as np
import numpy.typing as npt

from catanc.errors import LoopError
from catanc.runtime.compiled.arrays import Walk

WAIT, RUN_DUE = 0, 1
"""The entry's modes: :func:`~catanc.runtime.compiled.walk.wait`, or ``run_due`` then ``fire_clocks``."""

Layout = tuple[tuple[str, int], ...]
"""Per field of :class:`Walk`: its dtype's name and its dimensions."""

NUMBA_HELPERS = (
    "NRT_Free",
    "NRT_MemInfo_call_dtor",
    "numba_do_raise",
    "numba_gil_ensure",
    "numba_gil_release",
    "numba_runtime_build_excinfo_struct",
    "numba_unpickle",
)
"""numba's runtime functions the object names: the C wrapper's path for an exception, which the walk (numpy's
error model, no allocation) never takes, and the release of arrays the walk's descriptors never own."""


def layout_of(walk: Walk) -> Layout:
    return tuple((array.dtype.name, array.ndim) for array in walk)


def describe(walk: Walk, layout: Layout) -> npt.NDArray[np.int64]:
    """``walk`` as the entry reads it; ``TypeError`` if it is not laid out as the object file was compiled for."""
    if layout_of(walk) != layout:
        raise TypeError(f"a walk laid out as {layout_of(walk)}, compiled for {layout}")
    words: list[int] = []
    for array in walk:
        if not array.flags.c_contiguous:
            raise TypeError("a walk's array is not C-contiguous")
        words.append(array.ctypes.data)
        words.extend(array.shape)
    return np.array(words, dtype=np.int64)


def _unreachable() -> None:
    os.write(2, b"catanc run: the compiled walk took numba's exception path, which it has none of; aborting\n")
    os.abort()  # the watchdog restores the threads


_UNREACHABLE = ctypes.CFUNCTYPE(None)(_unreachable)  # kept for the process's life: the linked code holds its address

_Entry = ctypes.CFUNCTYPE(
    ctypes.c_int64, ctypes.c_void_p, ctypes.c_int64, ctypes.c_void_p, ctypes.c_int64, ctypes.c_double
)


class WalkEntry:
    """The walk's entry point, linked from ``code`` (an object file) whose entry is named ``symbol``."""

    def __init__(self, code: bytes, symbol: str, layout: Layout) -> None:
        import llvmlite.binding as llvm  # noqa: PLC0415 - LLVM's library only where the compiled loop runs

        if not code.startswith(b"\x7fELF"):  # LLVM's loader trusts its input (garbage crashes it); the stamp's
            raise LoopError("not an object file")  # digest vouches for the rest of a file the build wrote
        try:
            llvm.initialize_native_target()
            llvm.initialize_native_asmprinter()
            for name in NUMBA_HELPERS:  # where numba is loaded (tests, the build) its own stay
                if not llvm.address_of_symbol(name):
                    llvm.add_symbol(name, ctypes.cast(_UNREACHABLE, ctypes.c_void_p).value)
            machine = llvm.Target.from_default_triple().create_target_machine(jit=True)
            self._engine = llvm.create_mcjit_compiler(llvm.parse_assembly(""), machine)
            self._engine.add_object_file(llvm.ObjectFileRef.from_data(code))
            self._engine.finalize_object()
            address = self._engine.get_function_address(symbol)
        except RuntimeError as exc:  # llvmlite's error for an object that does not link
            raise LoopError(str(exc)) from None
        if not address:
            raise LoopError(f"the object file has no {symbol}")
        self._call = _Entry(address)
        self.layout = layout
        self._walk: Walk | None = None
        self._descriptor = np.zeros(0, dtype=np.int64)

    def _describe(self, walk: Walk) -> int:
        if walk is not self._walk:  # a walk laid out again: new arrays
            self._descriptor = describe(walk, self.layout)
            self._walk = walk
        return int(self._descriptor.ctypes.data)

    def wait(self, walk: Walk, polled: npt.NDArray[np.int32], until_ms: float) -> int:
        """:func:`~catanc.runtime.compiled.walk.wait` on ``polled`` (``struct pollfd`` as int32 pairs)."""
        if polled.dtype != np.int32 or not polled.flags.c_contiguous:
            raise TypeError("polled: a C-contiguous int32 array")
        return int(self._call(self._describe(walk), WAIT, polled.ctypes.data, polled.size // 2, until_ms))

    def run_due(self, walk: Walk, now_ms: float) -> int:
        """:func:`~catanc.runtime.compiled.walk.run_due`, then ``fire_clocks`` if it is done."""
        return int(self._call(self._describe(walk), RUN_DUE, None, 0, now_ms))
