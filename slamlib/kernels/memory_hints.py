"""Memory hints for the Numba CPU kernels: software prefetch, non-temporal whole-line stores, a store fence.

A kernel that streams arrays much larger than the caches (``transform_points`` on 1e7..1e8 points) is bound by
memory traffic, not arithmetic. Two hardware behaviours decide that traffic, and plain loads and stores leave
both on the table:

* **Read for ownership.** A plain store to a line that is not in cache first reads the line from memory, so
  writing ``B`` fresh bytes moves ``2 B``. A *non-temporal* store of a whole 64-byte line goes to memory
  through a write-combining buffer without that read (Intel 64 and IA-32 Architectures Optimization Reference
  Manual, "Non-temporal stores"; Intel SDM vol. 1, 10.4.6.2). An out-of-place transform then moves 24 bytes
  per point instead of 36, as ``memcpy`` does for large copies (glibc switches to non-temporal stores above
  its ``x86_non_temporal_threshold``). Only *whole, aligned* lines help: a line written partly by
  non-temporal and partly by plain stores is flushed half-filled and read back; measured here, an output 16
  bytes off the line grid made the transform 4x slower than an aligned one. The data then is not in cache,
  so a kernel uses these stores only for outputs too large to be there when they are read.
* **Prefetch.** A core's hardware prefetcher follows a stream within a 4 KiB page and keeps only a few lines
  in flight; a software prefetch a fixed distance ahead keeps more reads outstanding (measured: in-place
  transform of 1e8 points 52 -> 41 ms on 2 Xeon cores).

Non-temporal stores are weakly ordered (Intel SDM vol. 3, 8.2.2 and the ``MOVNTPS`` entry: follow them with
``SFENCE``): a kernel ends its stores with :func:`store_fence` before other threads may read the output.

Each hint is a plain Python function (its meaning, used when Numba's JIT is disabled, e.g. by the mutation
runs) with a Numba ``overload`` that emits the LLVM hint: ``!nontemporal`` store metadata, ``llvm.prefetch``,
and ``llvm.x86.sse.sfence`` on x86-64 (a sequentially consistent ``fence`` elsewhere). The first two are
target-independent LLVM: a target without the instructions lowers them to a plain store and to nothing.
"""

from __future__ import annotations

import platform

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload

#: Bytes per cache line (x86-64, and the granularity of write combining).
LINE_BYTES = 64
#: float32 values per cache line: what :func:`stream_line` writes.
LINE_F32 = LINE_BYTES // 4

# Numba compiles for the host: x86-64 gets the explicit ``sfence`` the SDM prescribes after non-temporal stores
_X86 = platform.machine().lower() in ("x86_64", "amd64")
# llvm.prefetch operands: read (not write), locality 3 (keep in all cache levels), data cache
_PREFETCH_READ, _PREFETCH_KEEP, _PREFETCH_DATA = 0, 3, 1


def stream_line(dst, i, src, j):
    """``dst[i:i + 16] = src[j:j + 16]`` (float32, 1-D): one whole 64-byte line, stored non-temporally when
    compiled. ``dst[i]`` must start a line (address a multiple of :data:`LINE_BYTES`); ``src`` may be
    unaligned. Indexes are not checked."""
    dst[i : i + LINE_F32] = src[j : j + LINE_F32]


def prefetch(arr, i):
    """Hint that ``arr[i]`` will be read soon (1-D array, ``i`` unsigned; no effect on any value, and an index
    past the end is harmless: prefetches do not fault)."""


def store_fence():
    """Order every earlier store, non-temporal ones included, before every later memory access."""


@intrinsic
def _stream_line_ir(typingctx, dst, i, src, j):
    sig = types.void(dst, types.uint64, src, types.uint64)

    def codegen(context, builder, sig, args):
        d, di, s, sj = args
        vec = ir.VectorType(ir.FloatType(), LINE_F32)
        d_arr = context.make_array(sig.args[0])(context, builder, d)
        s_arr = context.make_array(sig.args[2])(context, builder, s)
        src_ptr = builder.bitcast(builder.gep(s_arr.data, [sj]), vec.as_pointer())
        dst_ptr = builder.bitcast(builder.gep(d_arr.data, [di]), vec.as_pointer())
        line = builder.load(src_ptr, align=4)
        store = builder.store(line, dst_ptr, align=LINE_BYTES)
        store.set_metadata(
            "nontemporal", builder.module.add_metadata([ir.Constant(ir.IntType(32), 1)])
        )
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _prefetch_ir(typingctx, arr, i):
    sig = types.void(arr, types.uint64)

    def codegen(context, builder, sig, args):
        a, ia = args
        i32 = ir.IntType(32)
        a_arr = context.make_array(sig.args[0])(context, builder, a)
        ptr = builder.bitcast(builder.gep(a_arr.data, [ia]), ir.IntType(8).as_pointer())
        fn = cgutils.get_or_insert_function(
            builder.module,
            ir.FunctionType(ir.VoidType(), [ptr.type, i32, i32, i32]),
            "llvm.prefetch.p0",
        )
        builder.call(
            fn,
            [ptr]
            + [
                ir.Constant(i32, k)
                for k in (_PREFETCH_READ, _PREFETCH_KEEP, _PREFETCH_DATA)
            ],
        )
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _store_fence_ir(typingctx):
    def codegen(context, builder, sig, args):
        # LLVM lowers a seq_cst fence to ``lock or``, which the SDM does not promise orders WC stores
        if _X86:
            sfence = cgutils.get_or_insert_function(
                builder.module, ir.FunctionType(ir.VoidType(), []), "llvm.x86.sse.sfence"
            )
            builder.call(sfence, [])
        else:
            builder.fence("seq_cst")
        return context.get_dummy_value()

    return types.void(), codegen


@overload(stream_line, inline="always")
def _ol_stream_line(dst, i, src, j):
    return lambda dst, i, src, j: _stream_line_ir(dst, i, src, j)


@overload(prefetch, inline="always")
def _ol_prefetch(arr, i):
    return lambda arr, i: _prefetch_ir(arr, i)


@overload(store_fence, inline="always")
def _ol_store_fence():
    return lambda: _store_fence_ir()
