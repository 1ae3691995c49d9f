"""One sample of a block of parameter sets, as LLVM vector code: the operations ``lanes`` composes.

A block is ``LANES`` sets whose numbers sit in rows of a work array ``W``
(one row per quantity, ``ROW_*``), eight sets to an AVX-512 register
(``simd.VEC``).  Each intrinsic below is a loop over the block's vectors written
out at compile time; the per-vector pieces (``_step_vector``, ``_flip_vector``,
``_land_vector``, ``_send_vector``, ``_emit_state``, ``_emit_command``) are shared, so the
one-pass intrinsics (``advance``, ``advance_queued``) do exactly what the
separate ones do, in the same order per set.

Every sum is in ``kernels``' order, ((P0 I + P1 w) + P2 delta) + P9 u, with no
fused multiply-adds (numba does not contract), so each set gets the single
call's bits.  numba cannot express vector registers, hence LLVM IR.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic
from numba.np.arrayobj import make_array

from pipeline.model.kernels import TIME_EPS
from pipeline.model.simd import V8 as _V8, VEC, const as _const, splat as _splat

# Sets per block: their matrices (2 lengths: 12 kB) and state stay in L1; their output rows are long enough
# to stream.
LANES = 64
# Rows of a block's work array W (each LANES wide): state, command (two rows: before and after a sample),
# motor voltage, drive, guard threshold, loop delay, the next command on its way (arrival instant, volts).
ROW_I, ROW_W, ROW_DELTA, ROW_D0, ROW_D1, ROW_U, ROW_V, ROW_THR, ROW_TD, ROW_NEXT, ROW_NV = range(11)
WORK_ROWS = 11
# Gamma(h - a) remembered per set (split lengths of a fixed Td: a few).
MAX_SPLITS = 8
# Entries of one step length in a block's step matrices: Phi (9) and Gamma (3), a row of LANES sets each.
STEP_ENTRIES = 12 * LANES

_I64 = ir.IntType(64)
_B8 = ir.VectorType(ir.IntType(8), VEC)
_M8 = ir.VectorType(ir.IntType(1), VEC)
_NONE = ir.Constant(_B8, [0] * VEC)


def _index(b, base, offset: int):
    """base (an i64 value) + a constant offset."""
    return b.add(base, ir.Constant(_I64, offset))


def _any(b, mask):
    return b.icmp_unsigned("!=", b.bitcast(mask, ir.IntType(VEC)), ir.Constant(ir.IntType(VEC), 0))


def _count(b, mask):
    return b.zext(b.ctpop(b.bitcast(mask, ir.IntType(VEC))), _I64)


class _Rows:
    """Loads and stores of eight-set vectors of one C-contiguous array argument."""

    def __init__(self, context, b, ty, value):
        self.b = b
        self.data = make_array(ty)(context, b, value).data

    def _ptr(self, index, vec):
        return self.b.bitcast(self.b.gep(self.data, [index]), vec.as_pointer())

    def load(self, index, vec=_V8):
        return self.b.load(self._ptr(index, vec), align=8 if vec is _V8 else 1)

    def store(self, index, x, vec=_V8, align=8):
        return self.b.store(x, self._ptr(index, vec), align=align)

    def mask(self, v: int):
        """Lanes of vector v whose byte (a uint8 array) is non-zero."""
        return self.b.icmp_unsigned("!=", self.load(ir.Constant(_I64, VEC * v), _B8), _NONE)

    def flag(self, v: int, mask):
        """Bytes of vector v: 1 where ``mask``, else 0."""
        x = self.b.zext(mask, _B8)
        self.store(ir.Constant(_I64, VEC * v), x, _B8, align=1)

    def row(self, row, v: int):
        """Vector v of work row ``row`` (a constant row number or an i64 value)."""
        return self.load(self._row_index(row, v))

    def set_row(self, row, v: int, x):
        self.store(self._row_index(row, v), x)

    def _row_index(self, row, v: int):
        if isinstance(row, int):
            return ir.Constant(_I64, LANES * row + VEC * v)
        return self.b.add(self.b.mul(row, ir.Constant(_I64, LANES)), ir.Constant(_I64, VEC * v))


def _rows(context, b, signature, args, *which):
    return [_Rows(context, b, signature.args[i], args[i]) for i in which]


# ----------------------------------------------------------------- per vector

def _step_vector(b, P, W, p, v: int, d_row, own=None, on_row=None):
    """Vector v one step on: its new (I, w, delta) and its command d.  u = d V, or where ``own`` is 0 (a set
    with a queue) the motor's voltage U.  ``on_row(r, x)`` is called as soon as row r is computed (its stores
    then interleave with the next row's arithmetic)."""
    pe = [P.load(_index(b, p, LANES * e + VEC * v)) for e in range(12)]
    x = [W.row(r, v) for r in (ROW_I, ROW_W, ROW_DELTA)]
    dq = W.row(d_row, v)
    u = b.fmul(dq, W.row(ROW_V, v))
    if own is not None:
        u = b.select(own.mask(v), u, W.row(ROW_U, v))
    new = []
    for r in range(3):
        acc = b.fadd(b.fmul(pe[3 * r], x[0]), b.fmul(pe[3 * r + 1], x[1]))
        acc = b.fadd(acc, b.fmul(pe[3 * r + 2], x[2]))
        new.append(b.fadd(acc, b.fmul(pe[9 + r], u)))
        if on_row is not None:
            on_row(r, new[r])
    return new, dq


def _flip_vector(b, W, v: int, dq, delta):
    """The sampled guard: -d where d delta >= threshold, else d (a select: the command is +-1 here)."""
    flag = b.fcmp_ordered(">=", b.fmul(dq, delta), W.row(ROW_THR, v))
    return b.select(flag, b.fneg(dq), dq)


def _land_vector(b, W, P, BK, BG, p, v: int, state, tk, limit, h, used):
    """The commands on their way (rows ROW_NEXT, ROW_NV) arriving before ``limit`` (t_k+1 - TIME_EPS) in the
    step from tk (length h): the motor takes their voltage and the state (allocas, updated) gets
    ``kernels._delayed``'s correction 0 + Gamma(h - a) du.

    Gamma(h - a) is the step's own Gamma (a <= TIME_EPS) or the set's split
    cache entry for the key ``step_key(h - a)``, numba's round(x, 12), which
    is rint(x 1e12) / 1e12 -- the same operations here: BK (slot, lane)
    keys, BG (slot, row, lane) Gammas, slots 0..used-1.  A set whose cache
    lacks the key is left as it was; returns those sets' mask.
    """
    nxt = W.row(ROW_NEXT, v)
    due = b.fcmp_ordered("<", nxt, _splat(b, limit))
    missing = cgutils.alloca_once_value(b, ir.Constant(_M8, [0] * VEC))
    with b.if_then(_any(b, due), likely=False):
        U, NV = W.row(ROW_U, v), W.row(ROW_NV, v)
        du = b.fsub(NV, U)
        a = b.fsub(nxt, _splat(b, tk))
        rint = cgutils.get_or_insert_function(b.module, ir.FunctionType(_V8, [_V8]), "llvm.rint.v8f64")
        key = b.fdiv(b.call(rint, [b.fmul(b.fsub(_splat(b, h), a), _const(1e12))]), _const(1e12))
        g = [cgutils.alloca_once_value(b, _const(0.0)) for _ in range(3)]
        found = cgutils.alloca_once_value(b, ir.Constant(_M8, [0] * VEC))
        with cgutils.for_range(b, used) as loop:          # the slots in use only
            hit = b.fcmp_ordered("==", key, BK.row(loop.index, v))
            b.store(b.or_(b.load(found), hit), found)
            first = b.mul(loop.index, ir.Constant(_I64, 3))
            for r in range(3):
                b.store(b.select(hit, BG.row(b.add(first, ir.Constant(_I64, r)), v), b.load(g[r])), g[r])
        at_start = b.fcmp_ordered("<=", a, _const(TIME_EPS))
        gamma = [b.select(at_start, P.load(_index(b, p, (9 + r) * LANES + VEC * v)), b.load(g[r])) for r in range(3)]
        moved = b.fcmp_unordered("!=", du, _const(0.0))
        miss = b.and_(b.and_(due, moved), b.not_(b.or_(at_start, b.load(found))))
        ok = b.and_(due, b.not_(miss))
        apply = b.and_(ok, moved)
        for r in range(3):
            e = b.fadd(_const(0.0), b.fmul(gamma[r], du))
            x = b.load(state[r])
            b.store(b.select(apply, b.fadd(x, e), x), state[r])
        W.set_row(ROW_U, v, b.select(ok, NV, U))
        W.set_row(ROW_NEXT, v, b.select(ok, _const(np.inf), nxt))
        b.store(miss, missing)
    return b.load(missing)


def _send_vector(b, W, v: int, dq, dn, t_now, own, ringed, late):
    """The commands decided at t_now: a delayed set whose command changed and has none on its way gets it in
    rows ROW_NEXT (t_now + Td) and ROW_NV (d V volts), as ``kernels._delayed`` files it.  Changed sets that
    already have one on their way (or a ring) are the scalar ring's: ``late(mask)`` is called with them
    (often none); returns how many.

    No branch: whether a vector's command changed is known only at the end of
    its step's chain, and about one vector-sample in five has a change, so a
    branch on it was mispredicted often and late -- ~15 % of a delayed
    batch (interleaved A/B) against a few selects and stores.
    """
    changed = b.and_(b.fcmp_unordered("!=", dq, dn), b.not_(own.mask(v)))   # own 0: a set with a queue
    nxt = W.row(ROW_NEXT, v)
    free = b.and_(b.fcmp_ordered("==", nxt, _const(np.inf)), b.not_(ringed.mask(v)))
    simple = b.and_(changed, free)
    W.set_row(ROW_NEXT, v, b.select(simple, b.fadd(_splat(b, t_now), W.row(ROW_TD, v)), nxt))
    W.set_row(ROW_NV, v, b.select(simple, b.fmul(dn, W.row(ROW_V, v)), W.row(ROW_NV, v)))
    busy = b.and_(changed, b.not_(free))
    late(busy)
    return _count(b, busy)


def _emit_row(b, Y, y, stride, v: int, r: int, x):
    """Vector v's row r (current, omega, delta) to Y[y + r stride] as a whole 64-byte line by a non-temporal
    store (Y + y 64-byte aligned)."""
    at = b.add(y, b.add(b.mul(stride, ir.Constant(_I64, r)), ir.Constant(_I64, VEC * v)))
    Y.store(at, x, align=8 * VEC).set_metadata("nontemporal", b.module.add_metadata([ir.Constant(ir.IntType(32), 1)]))


def _emit_state(b, Y, y, stride, v: int, state):
    """Vector v's current, omega and delta (``_emit_row``)."""
    for r in range(3):
        _emit_row(b, Y, y, stride, v, r, state[r])


def _emit_command(b, dirs, di, v: int, dn):
    """Vector v's command as int8 to dirs[di + 8 v]."""
    dirs.store(_index(b, di, VEC * v), b.fptosi(dn, _B8), _B8, align=1)


# ----------------------------------------------------------------- whole blocks

@intrinsic
def step(typingctx, P, p, W, d_row):
    """The block one step on, commands acting at once: S <- Phi S + Gamma u, u = d V.  P: the block's step
    matrices, this step length's from flat index p; d_row: the command's work row."""
    def codegen(context, b, signature, args):
        P, W = _rows(context, b, signature, args, 0, 2)
        for v in range(LANES // VEC):
            new, _ = _step_vector(b, P, W, args[1], v, args[3])
            for r in range(3):
                W.set_row(r, v, new[r])
        return context.get_dummy_value()
    return types.void(P, types.intp, W, types.intp), codegen


@intrinsic
def step_motor(typingctx, P, p, W, d_row, own):
    """``step`` where a set may have a queue (own[l] == 0): its u is the motor's voltage (row ROW_U)."""
    def codegen(context, b, signature, args):
        P, W, own = _rows(context, b, signature, args, 0, 2, 4)
        for v in range(LANES // VEC):
            new, _ = _step_vector(b, P, W, args[1], v, args[3], own)
            for r in range(3):
                W.set_row(r, v, new[r])
        return context.get_dummy_value()
    return types.void(P, types.intp, W, types.intp, own), codegen


@intrinsic
def flip(typingctx, W, d_old, d_new):
    """The sampled guard for the block: row d_new from row d_old and the state."""
    def codegen(context, b, signature, args):
        (W,) = _rows(context, b, signature, args, 0)
        for v in range(LANES // VEC):
            W.set_row(args[2], v, _flip_vector(b, W, v, W.row(args[1], v), W.row(ROW_DELTA, v)))
        return context.get_dummy_value()
    return types.void(W, types.intp, types.intp), codegen


@intrinsic
def fill(typingctx, W, row, value):
    """Work row ``row`` = value (every set gets the logged command)."""
    def codegen(context, b, signature, args):
        (W,) = _rows(context, b, signature, args, 0)
        for v in range(LANES // VEC):
            W.set_row(args[1], v, _splat(b, args[2]))
        return context.get_dummy_value()
    return types.void(W, types.intp, types.float64), codegen


@intrinsic
def land(typingctx, W, P, p, BK, BG, used, tk, limit, h, flags):
    """``_land_vector`` for the block, the state in W; flags[l] = 1 where set l's split length is not in its
    cache (the caller lands it); returns how many."""
    def codegen(context, b, signature, args):
        W, P, BK, BG, flags = _rows(context, b, signature, args, 0, 1, 3, 4, 9)
        count = ir.Constant(_I64, 0)
        for v in range(LANES // VEC):
            state = [cgutils.alloca_once_value(b, W.row(r, v)) for r in range(3)]
            miss = _land_vector(b, W, P, BK, BG, args[2], v, state, args[6], args[7], args[8], args[5])
            for r in range(3):
                W.set_row(r, v, b.load(state[r]))
            flags.flag(v, miss)
            count = b.add(count, _count(b, miss))
        return count
    sig = types.int64(W, P, types.intp, BK, BG, types.intp, types.float64, types.float64, types.float64, flags)
    return sig, codegen


@intrinsic
def send(typingctx, W, d_old, d_new, t_now, own, ringed, flags):
    """``_send_vector`` for the block; flags[l] = 1 where set l's command goes to the ring; returns how many."""
    def codegen(context, b, signature, args):
        W, own, ringed, flags = _rows(context, b, signature, args, 0, 4, 5, 6)
        count = ir.Constant(_I64, 0)
        for v in range(LANES // VEC):
            count = b.add(count, _send_vector(b, W, v, W.row(args[1], v), W.row(args[2], v), args[3], own, ringed,
                                              lambda busy, v=v: flags.flag(v, busy)))
        return count
    return types.int64(W, types.intp, types.intp, types.float64, own, ringed, flags), codegen


@intrinsic
def emit(typingctx, Y, y, stride, W, dirs, di, d_row):
    """The block's sample outputs (``_emit_state``, ``_emit_command``) from its work rows."""
    def codegen(context, b, signature, args):
        Y, W, dirs = _rows(context, b, signature, args, 0, 3, 4)
        for v in range(LANES // VEC):
            _emit_state(b, Y, args[1], args[2], v, [W.row(r, v) for r in range(3)])
            _emit_command(b, dirs, args[5], v, W.row(args[6], v))
        return context.get_dummy_value()
    return types.void(Y, types.intp, types.intp, W, dirs, types.intp, types.intp), codegen


@intrinsic
def advance(typingctx, P, p, W, d_old, d_new, Y, y, stride, dirs, di):
    """``step``, ``flip`` and ``emit`` in one pass over the block's vectors (a block with no queue past the
    controller's start): each vector's outputs leave right after it is computed, so the stores spread over
    the arithmetic instead of queueing behind it."""
    def codegen(context, b, signature, args):
        P, W, Y, dirs = _rows(context, b, signature, args, 0, 2, 5, 8)
        for v in range(LANES // VEC):
            def out(r, x, v=v):                                 # stored and sent out as soon as computed
                W.set_row(r, v, x)
                _emit_row(b, Y, args[6], args[7], v, r, x)
            new, dq = _step_vector(b, P, W, args[1], v, args[3], on_row=out)
            dn = _flip_vector(b, W, v, dq, new[2])
            W.set_row(args[4], v, dn)
            _emit_command(b, dirs, args[9], v, dn)
        return context.get_dummy_value()
    return types.void(P, types.intp, W, types.intp, types.intp, Y, types.intp, types.intp, dirs, types.intp), codegen


@intrinsic
def advance_queued(typingctx, P, p, W, d_old, d_new, own, BK, BG, used, tk, limit, h, t_now, ringed, Y, y, stride,
                   dirs, di, odd, busy):
    """A block with delayed sets one sample on, in closed loop past the controller's start, in one pass over
    its vectors: ``step_motor``, ``land``, ``flip``, ``send`` and ``emit``.

    A vector where a set's split length is not in its cache is stored before
    the guard and flagged in ``odd`` (1 for that set, 2 for the others of its
    vector): the caller lands that set and finishes the vector one set at a
    time.  Sets whose new command finds one on its way are flagged in
    ``busy`` for the ring (every vector sent from writes its bytes; ``odd``
    is written only where raised).  The caller clears the flags it handles.
    Returns flagged vectors + 2^32 x busy sets.
    """
    def codegen(context, b, signature, args):
        P, W, own, BK, BG, ringed, Y, dirs, odd, busy = _rows(context, b, signature, args,
                                                              0, 2, 5, 6, 7, 13, 14, 17, 19, 20)
        p, d_old, d_new, used, tk, limit, h, t_now, y, stride, di = (args[i] for i in
                                                                     (1, 3, 4, 8, 9, 10, 11, 12, 15, 16, 18))
        deferred = cgutils.alloca_once_value(b, ir.Constant(_I64, 0))
        waiting = cgutils.alloca_once_value(b, ir.Constant(_I64, 0))
        for v in range(LANES // VEC):
            new, dq = _step_vector(b, P, W, p, v, d_old, own)
            state = [cgutils.alloca_once_value(b, x) for x in new]
            miss = _land_vector(b, W, P, BK, BG, p, v, state, tk, limit, h, used)
            new = [b.load(s) for s in state]
            for r in range(3):
                W.set_row(r, v, new[r])
            with b.if_else(_any(b, miss), likely=False) as (unusual, usual):
                with unusual:                               # the caller finishes this vector
                    odd.store(ir.Constant(_I64, VEC * v), b.select(miss, ir.Constant(_B8, [1] * VEC),
                                                                   ir.Constant(_B8, [2] * VEC)), _B8, align=1)
                    b.store(b.add(b.load(deferred), ir.Constant(_I64, 1)), deferred)
                with usual:
                    dn = _flip_vector(b, W, v, dq, new[2])
                    W.set_row(d_new, v, dn)
                    late = _send_vector(b, W, v, dq, dn, t_now, own, ringed, lambda m, v=v: busy.flag(v, m))
                    b.store(b.add(b.load(waiting), late), waiting)
                    _emit_state(b, Y, y, stride, v, new)
                    _emit_command(b, dirs, di, v, dn)
        return b.add(b.load(deferred), b.shl(b.load(waiting), ir.Constant(_I64, 32)))
    sig = types.int64(P, types.intp, W, types.intp, types.intp, own, BK, BG, types.intp, types.float64,
                      types.float64, types.float64, types.float64, ringed, Y, types.intp, types.intp, dirs,
                      types.intp, odd, busy)
    return sig, codegen


@intrinsic
def claim(typingctx, counters, i):
    """counters[i] += 1, atomically; returns the value before (threads sharing the counters each get their
    own numbers)."""
    def codegen(context, b, signature, args):
        (counters,) = _rows(context, b, signature, args, 0)
        return b.atomic_rmw("add", b.gep(counters.data, [args[1]]), ir.Constant(_I64, 1), "monotonic")
    return types.int64(counters, types.intp), codegen


@intrinsic
def store_fence(typingctx):
    """Order the non-temporal stores before anything after (they bypass the usual store ordering)."""
    def codegen(context, b, signature, args):
        b.fence("seq_cst")
        return context.get_dummy_value()
    return types.void(), codegen
