"""The compiled walk as an object file: numba compiles it behind one C entry point, llvmlite emits it.

The entry (:func:`_entry`, a numba ``cfunc``) rebuilds the :class:`Walk` from a descriptor of
addresses and shapes (:func:`catanc.runtime.compiled.entry.describe`) and runs
:func:`~catanc.runtime.compiled.walk.wait` or :func:`~catanc.runtime.compiled.walk.run_due` and
:func:`~catanc.runtime.compiled.walk.fire_clocks`.  numba links the walk's functions into the
entry's module; :func:`object_code` has LLVM emit that module as machine code for this CPU, which
:class:`~catanc.runtime.compiled.entry.WalkEntry` links into a process that never imports numba.
Imports numba: only the build (:func:`catanc.runtime.compiled.ready.build`) loads this module.
"""

from __future__ import annotations

import functools
from typing import Any

import llvmlite.binding as llvm
import numba
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic
from numba.np.arrayobj import populate_array

from catanc.control.schedule import RuntimeSchedule
from catanc.runtime.compiled import state as compiled_state
from catanc.runtime.compiled import walk as cw
from catanc.runtime.compiled.arrays import DONE, Walk
from catanc.runtime.compiled.entry import WAIT, Layout, layout_of
from catanc.runtime.enforcer.nodes import Wiring
from catanc.runtime.enforcer.runs import RunBook
from catanc.runtime.linux.levels import Levels

ENTRY_SIGNATURE = types.int64(
    types.CPointer(types.int64), types.int64, types.CPointer(types.int32), types.int64, types.float64
)
"""(descriptor, mode, polled, polled's count, until or now): see :class:`~catanc.runtime.compiled.entry.WalkEntry`."""


@functools.cache
def sample_walk() -> Walk:
    """A walk of nothing, laid out as every walk is (the same fields, dtypes and dimensions)."""
    empty = RuntimeSchedule(1, {}, ())
    walk, _, _ = compiled_state.install(
        empty, Wiring(0, empty, {}, {}, {}), RunBook([], {}, lambda _e: None), Levels(rt=False), 0.0
    )
    return walk


@intrinsic  # type: ignore[untyped-decorator]
def _walk_from(_typingctx: Any, _descriptor: Any) -> Any:
    """The :class:`Walk` a descriptor describes: each field an array over the memory it names (not owned)."""
    walk_type = numba.typeof(sample_walk())
    signature = walk_type(types.CPointer(types.int64))

    def codegen(context: Any, builder: Any, _signature: Any, args: Any) -> Any:
        words = args[0]
        word = 0

        def next_word() -> Any:
            nonlocal word
            value = builder.load(builder.gep(words, [context.get_constant(types.intp, word)]))
            word += 1
            return value

        fields = []
        for array_type in walk_type.types:
            array = context.make_array(array_type)(context, builder)
            data = builder.inttoptr(next_word(), array.data.type)
            shape = [next_word() for _ in range(array_type.ndim)]
            itemsize = context.get_constant(types.intp, context.get_abi_sizeof(context.get_data_type(array_type.dtype)))
            strides: list[Any] = []
            step = itemsize
            for extent in reversed(shape):  # C order
                strides.insert(0, step)
                step = builder.mul(step, extent)
            populate_array(
                array,
                data=data,
                shape=cgutils.pack_array(builder, shape),
                strides=cgutils.pack_array(builder, strides),
                itemsize=itemsize,
                meminfo=None,
            )
            fields.append(array._getvalue())
        return context.make_tuple(builder, walk_type, fields)

    return signature, codegen


def _entry(descriptor: Any, mode: int, polled: Any, count: int, value: float) -> int:
    walk = _walk_from(descriptor)
    if mode == WAIT:
        return cw.wait(walk, numba.carray(polled, 2 * count), value)
    status = cw.run_due(walk, value)
    if status == DONE:
        status = cw.fire_clocks(walk, value)
    return status


def object_code() -> tuple[bytes, str, Layout]:
    """The walk's entry compiled for this CPU: the object file, the entry's symbol and the walk's layout.

    About a minute of one CPU where numba's cache of the walk is cold, a few seconds where it is warm."""
    entry = numba.cfunc(ENTRY_SIGNATURE, error_model="numpy")(_entry)
    llvm.initialize_native_target()
    llvm.initialize_native_asmprinter()
    module = llvm.parse_assembly(entry.inspect_llvm())
    module.verify()
    machine = llvm.Target.from_default_triple().create_target_machine(
        cpu=llvm.get_host_cpu_name(),
        features=llvm.get_host_cpu_features().flatten(),
        opt=3,
        reloc="static",
        codemodel="jitdefault",
        jit=True,
    )
    return machine.emit_object(module), entry.native_name, layout_of(sample_walk())
