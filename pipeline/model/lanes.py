"""Many parameter sets side by side (``simulate_batch``): the automaton of ``kernels``, a block of sets at a time.

``kernels.run_linear_batch`` follows one set sample by sample: each step waits
on the previous one (a chain of multiply-adds), so a thousand sets cost a
thousand chains.  Here a block of ``LANES`` sets moves together through all
the samples before the next block starts:

- the block's step matrices (12 numbers per set and distinct step length) and
  its state stay in L1 for the whole recording (streaming every set's
  matrices from L2 at every sample cost more than the arithmetic);
- each step is LLVM vector code, eight sets to an AVX-512 register: every set
  moves by its own step matrices with the motor voltage it had at the start
  of the step (``_step``), and the sampled guard is a sign flip when
  d * delta >= ``guard_threshold`` (``_flip``: no division, a select); the
  block's eight-set vectors are independent, so their chains overlap;
- a delayed set's command travels in two vector rows (arrival, volts) and
  lands inside the step it reaches the motor in, adding ``kernels._delayed``'s
  correction ``Gamma(h - a) du`` (``_send``, ``_land``); the rare set with
  several commands on their way, or a split length its cache lacks, is
  handled one set at a time;
- past the controller's start in closed loop, each sample is one pass over
  the block's vectors (``_advance``, ``_advance_queued``): a vector's outputs
  leave, as whole 64-byte lines by non-temporal stores, right after it is
  computed, so the 12.5 MB of 1000 sets x 500 samples stream out while the
  arithmetic goes on (writing them after each step, or with ordinary stores
  that read every line first, cost as much again).

Per set the operations and their order are those of ``kernels`` (the common
part is the first four terms of its sum, the correction the fifth), so a batch
equals the single calls to the last bit (tests/model/test_batch.py).
"""

from __future__ import annotations

import sys
import threading

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic
from numba.np.arrayobj import make_array

from pipeline.model.kernels import TIME_EPS, decide
from pipeline.model.linear import phi_gamma_into, phi_gamma_lanes, step_key, step_lengths

# Sets per vector: one AVX-512 register of float64, a 64-byte cache line.
VEC = 8
# Sets per block: their matrices (2 lengths: 12 kB) and state stay in L1; their output rows are long enough
# to stream.
LANES = 64
# Rows of a block's work array W (each LANES wide): state, command (two rows: before and after a sample),
# motor voltage, drive, guard threshold, loop delay, the next command on its way (arrival instant, volts).
ROW_I, ROW_W, ROW_DELTA, ROW_D0, ROW_D1, ROW_U, ROW_V, ROW_THR, ROW_TD, ROW_NEXT, ROW_NV = range(11)
WORK_ROWS = 11
# Gamma(h - a) remembered per set (split lengths of a fixed Td: a few).
MAX_SPLITS = 8

_I64 = ir.IntType(64)
_V8 = ir.VectorType(ir.DoubleType(), VEC)
_B8 = ir.VectorType(ir.IntType(8), VEC)


def _ptr(context, builder, ty, value, index, vec=_V8):
    """Pointer to a ``vec`` at flat element ``index`` (an i64 value) of a C-contiguous array argument."""
    data = make_array(ty)(context, builder, value).data
    return builder.bitcast(builder.gep(data, [index]), vec.as_pointer())


def _at(builder, base, offset: int):
    """base (an i64 value, or None for 0) + a constant offset."""
    c = ir.Constant(_I64, offset)
    return c if base is None else builder.add(base, c)


def _row_index(builder, row, v: int):
    """Flat index of vector v of work row ``row`` (an i64 value or a constant row number)."""
    if isinstance(row, int):
        return ir.Constant(_I64, LANES * row + VEC * v)
    return builder.add(builder.mul(row, ir.Constant(_I64, LANES)), ir.Constant(_I64, VEC * v))


class _Rows:
    """Loads and stores of eight-set vectors of one array argument inside an intrinsic's codegen."""

    def __init__(self, context, builder, ty, value):
        self.c, self.b, self.ty, self.value = context, builder, ty, value

    def load(self, index, vec=_V8):
        return self.b.load(_ptr(self.c, self.b, self.ty, self.value, index, vec), align=8 if vec is _V8 else 1)

    def store(self, index, x, vec=_V8, align=8):
        return self.b.store(x, _ptr(self.c, self.b, self.ty, self.value, index, vec), align=align)

    def row(self, row, v: int):
        return self.load(_row_index(self.b, row, v))

    def set_row(self, row, v: int, x):
        self.store(_row_index(self.b, row, v), x)


def _step_codegen(motor: bool):
    def codegen(context, builder, signature, args):
        P, W = _Rows(context, builder, signature.args[0], args[0]), _Rows(context, builder, signature.args[2], args[2])
        p, d_row = args[1], args[3]
        own = _Rows(context, builder, signature.args[4], args[4]) if motor else None
        for v in range(LANES // VEC):
            pe = [P.load(_at(builder, p, LANES * e + VEC * v)) for e in range(12)]
            x = [W.row(r, v) for r in (ROW_I, ROW_W, ROW_DELTA)]
            u = builder.fmul(W.row(d_row, v), W.row(ROW_V, v))
            if motor:                       # a set with a queue: the voltage its motor has
                flags = own.load(ir.Constant(_I64, VEC * v), _B8)
                u = builder.select(builder.icmp_unsigned("!=", flags, ir.Constant(_B8, [0] * VEC)), u,
                                   W.row(ROW_U, v))
            for r in range(3):
                acc = builder.fadd(builder.fmul(pe[3 * r], x[0]), builder.fmul(pe[3 * r + 1], x[1]))
                acc = builder.fadd(acc, builder.fmul(pe[3 * r + 2], x[2]))
                W.set_row(r, v, builder.fadd(acc, builder.fmul(pe[9 + r], u)))
        return context.get_dummy_value()
    return codegen


@intrinsic
def _step(typingctx, P, p, W, d_row):
    """One step of a block whose commands act at once: S <- Phi S + Gamma u, u = d V.

    P: the block's step matrices, the 12 entries of this step's length from
    flat index p (a row of LANES sets each); W: the block's work rows, d_row
    the command's.  The sums in ``kernels``' order, ((P0 I + P1 w) + P2 delta)
    + P9 u, with no fused multiply-adds (numba does not contract), so each set
    gets the single call's bits.
    """
    return types.void(P, types.intp, W, types.intp), _step_codegen(False)


@intrinsic
def _step_motor(typingctx, P, p, W, d_row, own):
    """``_step`` where a set may have a queue (own[l] == 0): its u is the motor's voltage (row ROW_U)."""
    return types.void(P, types.intp, W, types.intp, own), _step_codegen(True)


@intrinsic
def _flip(typingctx, W, d_old, d_new):
    """The sampled guard for a block: d_new = d - 2 d [d delta >= threshold] (exact for d = +-1)."""
    sig = types.void(W, types.intp, types.intp)

    def codegen(context, builder, signature, args):
        W = _Rows(context, builder, signature.args[0], args[0])
        two = ir.Constant(_V8, [2.0] * VEC)
        for v in range(LANES // VEC):
            dq = W.row(args[1], v)
            flag = builder.uitofp(builder.fcmp_ordered(">=", builder.fmul(dq, W.row(ROW_DELTA, v)),
                                                       W.row(ROW_THR, v)), _V8)
            W.set_row(args[2], v, builder.fsub(dq, builder.fmul(builder.fmul(two, dq), flag)))
        return context.get_dummy_value()

    return sig, codegen


def _splat(builder, x):
    """An eight-lane vector of the scalar value x."""
    v = builder.insert_element(ir.Constant(_V8, ir.Undefined), x, ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(v, ir.Constant(_V8, ir.Undefined), ir.Constant(ir.VectorType(ir.IntType(32), VEC),
                                                                             [0] * VEC))


def _const(x: float):
    return ir.Constant(_V8, [x] * VEC)


def _mask_of(builder, rows, v: int):
    """Lanes of vector v whose byte in ``rows`` (a uint8 array argument) is non-zero."""
    return builder.icmp_unsigned("!=", rows.load(ir.Constant(_I64, VEC * v), _B8), ir.Constant(_B8, [0] * VEC))


def _count(builder, mask):
    return builder.zext(builder.ctpop(builder.bitcast(mask, ir.IntType(VEC))), _I64)


@intrinsic
def _land(typingctx, W, P, p, BK, BG, tk, limit, h, flags):
    """The commands reaching their motors inside the step from tk (length h), vectorised: where a set's
    command on its way (rows ROW_NEXT, ROW_NV) arrives before ``limit`` (t_k+1 - TIME_EPS), the motor takes
    its voltage and the state gets ``kernels._delayed``'s correction 0 + Gamma(h - a) du.

    Gamma(h - a) is the step's own Gamma (a <= TIME_EPS) or the set's split cache entry for the key
    ``step_key(h - a)`` (numba's round(x, 12): rint(x 1e12) / 1e12, the same operations): BK (slot, lane)
    keys, BG (slot, row, lane) Gammas.  A set whose cache lacks the key is left untouched and flagged for
    the scalar path; returns how many.
    """
    sig = types.int64(W, P, types.intp, BK, BG, types.float64, types.float64, types.float64, flags)

    def codegen(context, builder, signature, args):
        W, P, BK, BG, flags = (_Rows(context, builder, signature.args[i], args[i]) for i in (0, 1, 3, 4, 8))
        p, tk, limit, h = args[2], args[5], args[6], args[7]
        count = cgutils.alloca_once_value(builder, ir.Constant(_I64, 0))
        rint = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_V8, [_V8]), "llvm.rint.v8f64")
        no = ir.Constant(_B8, [0] * VEC)
        for v in range(LANES // VEC):
            nxt = W.row(ROW_NEXT, v)
            due = builder.fcmp_ordered("<", nxt, _splat(builder, limit))
            flags.store(ir.Constant(_I64, VEC * v), no, _B8, align=1)
            any_due = builder.icmp_unsigned("!=", builder.bitcast(due, ir.IntType(VEC)), ir.Constant(ir.IntType(VEC), 0))
            with builder.if_then(any_due, likely=False):
                U, NV = W.row(ROW_U, v), W.row(ROW_NV, v)
                du = builder.fsub(NV, U)
                a = builder.fsub(nxt, _splat(builder, tk))
                key = builder.fdiv(builder.call(rint, [builder.fmul(builder.fsub(_splat(builder, h), a), _const(1e12))]),
                                   _const(1e12))
                g = [_const(0.0)] * 3
                found = ir.Constant(ir.VectorType(ir.IntType(1), VEC), [0] * VEC)
                for slot in range(MAX_SPLITS):
                    hit = builder.fcmp_ordered("==", key, BK.row(slot, v))
                    found = builder.or_(found, hit)
                    g = [builder.select(hit, BG.row(3 * slot + r, v), g[r]) for r in range(3)]
                at_start = builder.fcmp_ordered("<=", a, _const(TIME_EPS))
                g = [builder.select(at_start, P.load(_at(builder, p, (9 + r) * LANES + VEC * v)), g[r]) for r in range(3)]
                moved = builder.fcmp_unordered("!=", du, _const(0.0))
                miss = builder.and_(builder.and_(due, moved), builder.not_(builder.or_(at_start, found)))
                ok = builder.and_(due, builder.not_(miss))
                apply = builder.and_(ok, moved)
                for r in range(3):
                    e = builder.fadd(_const(0.0), builder.fmul(g[r], du))
                    x = W.row(r, v)
                    W.set_row(r, v, builder.select(apply, builder.fadd(x, e), x))
                W.set_row(ROW_U, v, builder.select(ok, NV, U))
                W.set_row(ROW_NEXT, v, builder.select(ok, _const(np.inf), nxt))
                flags.store(ir.Constant(_I64, VEC * v), builder.zext(miss, _B8), _B8, align=1)
                builder.store(builder.add(builder.load(count), _count(builder, miss)), count)
        return builder.load(count)

    return sig, codegen


@intrinsic
def _fill(typingctx, W, row, value):
    """Work row ``row`` = value (every set gets the logged command)."""
    sig = types.void(W, types.intp, types.float64)

    def codegen(context, builder, signature, args):
        W = _Rows(context, builder, signature.args[0], args[0])
        for v in range(LANES // VEC):
            W.set_row(args[1], v, _splat(builder, args[2]))
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _send(typingctx, W, d_old, d_new, tk, queued, ringed, flags):
    """The commands decided at tk, vectorised: a delayed set whose command changed and has none on its way
    gets it in rows ROW_NEXT (tk + Td) and ROW_NV (d V volts), as ``kernels._delayed`` files it.  Sets that
    already have one on their way (or a ring) are flagged for the scalar ring; returns how many."""
    sig = types.int64(W, types.intp, types.intp, types.float64, queued, ringed, flags)

    def codegen(context, builder, signature, args):
        W, queued, ringed, flags = (_Rows(context, builder, signature.args[i], args[i]) for i in (0, 4, 5, 6))
        d_old, d_new, tk = args[1], args[2], args[3]
        count = cgutils.alloca_once_value(builder, ir.Constant(_I64, 0))
        no = ir.Constant(_B8, [0] * VEC)
        for v in range(LANES // VEC):
            dn = W.row(d_new, v)
            changed = builder.and_(builder.fcmp_unordered("!=", W.row(d_old, v), dn), _mask_of(builder, queued, v))
            flags.store(ir.Constant(_I64, VEC * v), no, _B8, align=1)
            any_changed = builder.icmp_unsigned("!=", builder.bitcast(changed, ir.IntType(VEC)),
                                                ir.Constant(ir.IntType(VEC), 0))
            with builder.if_then(any_changed, likely=False):
                nxt = W.row(ROW_NEXT, v)
                free = builder.and_(builder.fcmp_ordered("==", nxt, _const(np.inf)),
                                    builder.not_(_mask_of(builder, ringed, v)))
                simple = builder.and_(changed, free)
                busy = builder.and_(changed, builder.not_(free))
                W.set_row(ROW_NEXT, v, builder.select(simple, builder.fadd(_splat(builder, tk), W.row(ROW_TD, v)), nxt))
                W.set_row(ROW_NV, v, builder.select(simple, builder.fmul(dn, W.row(ROW_V, v)), W.row(ROW_NV, v)))
                flags.store(ir.Constant(_I64, VEC * v), builder.zext(busy, _B8), _B8, align=1)
                builder.store(builder.add(builder.load(count), _count(builder, busy)), count)
        return builder.load(count)

    return sig, codegen


@intrinsic
def _emit(typingctx, Y, y, stride, W, dirs, di, d_row):
    """A block's sample outputs: its current, omega and delta rows to Y[y], Y[y + stride], Y[y + 2 stride]
    (whole cache lines: Y + y 64-byte aligned), its command row as int8 to dirs[di:di + LANES]."""
    sig = types.void(Y, types.intp, types.intp, W, dirs, types.intp, types.intp)

    def codegen(context, builder, signature, args):
        Yr, W = _Rows(context, builder, signature.args[0], args[0]), _Rows(context, builder, signature.args[3], args[3])
        out = _Rows(context, builder, signature.args[4], args[4])
        y, stride, di, d_row = args[1], args[2], args[5], args[6]
        nontemporal = builder.module.add_metadata([ir.Constant(ir.IntType(32), 1)])
        for v in range(LANES // VEC):
            for r in range(3):
                at = builder.add(y, builder.add(builder.mul(stride, ir.Constant(_I64, r)), ir.Constant(_I64, VEC * v)))
                Yr.store(at, W.row(r, v), align=8 * VEC).set_metadata("nontemporal", nontemporal)
            out.store(_at(builder, di, VEC * v), builder.fptosi(W.row(d_row, v), _B8), _B8, align=1)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _advance(typingctx, P, p, W, d_old, d_new, Y, y, stride, dirs, di):
    """``_step``, ``_flip`` and ``_emit`` in one pass over a block's vectors (a block with no queue past
    the controller's start): each vector's outputs leave right after it is computed, so the stores spread
    over the arithmetic instead of queueing behind it."""
    sig = types.void(P, types.intp, W, types.intp, types.intp, Y, types.intp, types.intp, dirs, types.intp)

    def codegen(context, builder, signature, args):
        P, W, Yr, out = (_Rows(context, builder, signature.args[i], args[i]) for i in (0, 2, 5, 8))
        p, d_old, d_new, y, stride, di = args[1], args[3], args[4], args[6], args[7], args[9]
        nontemporal = builder.module.add_metadata([ir.Constant(ir.IntType(32), 1)])
        two = ir.Constant(_V8, [2.0] * VEC)
        for v in range(LANES // VEC):
            pe = [P.load(_at(builder, p, LANES * e + VEC * v)) for e in range(12)]
            x = [W.row(r, v) for r in (ROW_I, ROW_W, ROW_DELTA)]
            dq = W.row(d_old, v)
            u = builder.fmul(dq, W.row(ROW_V, v))
            new = []
            for r in range(3):
                acc = builder.fadd(builder.fmul(pe[3 * r], x[0]), builder.fmul(pe[3 * r + 1], x[1]))
                acc = builder.fadd(acc, builder.fmul(pe[3 * r + 2], x[2]))
                new.append(builder.fadd(acc, builder.fmul(pe[9 + r], u)))
                W.set_row(r, v, new[r])
                at = builder.add(y, builder.add(builder.mul(stride, ir.Constant(_I64, r)), ir.Constant(_I64, VEC * v)))
                Yr.store(at, new[r], align=8 * VEC).set_metadata("nontemporal", nontemporal)
            flag = builder.uitofp(builder.fcmp_ordered(">=", builder.fmul(dq, new[2]), W.row(ROW_THR, v)), _V8)
            dn = builder.fsub(dq, builder.fmul(builder.fmul(two, dq), flag))
            W.set_row(d_new, v, dn)
            out.store(_at(builder, di, VEC * v), builder.fptosi(dn, _B8), _B8, align=1)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _advance_queued(typingctx, P, p, W, d_old, d_new, own, BK, BG, used, tk, limit, h, t_now, queued, ringed, Y, y,
                    stride, dirs, di, odd, busy):
    """A block with delayed sets, one sample on in closed loop past the controller's start, in one pass
    over its vectors: ``_step_motor``, ``_land``, ``_flip``, ``_send`` and ``_emit`` (see them), so each
    vector's outputs leave right after it is computed.  ``used``: the split cache slots any set of the
    block has filled.

    A vector where a set's split length is not in its cache is stored
    before the guard and flagged in ``odd`` (1 for that set, 2 for the others
    of its vector): the caller lands that set and finishes the vector one set
    at a time.  Sets whose new command finds one on its way are flagged in
    ``busy`` for the ring.  Only flags are written: the caller clears them.
    Returns flagged vectors + 2^32 x busy sets.
    """
    sig = types.int64(P, types.intp, W, types.intp, types.intp, own, BK, BG, types.intp, types.float64,
                      types.float64, types.float64, types.float64, queued, ringed, Y, types.intp, types.intp, dirs,
                      types.intp, odd, busy)

    def codegen(context, builder, signature, args):
        P, W, own, BK, BG, queued, ringed, Yr, out, odd, busy = (
            _Rows(context, builder, signature.args[i], args[i]) for i in (0, 2, 5, 6, 7, 13, 14, 15, 18, 20, 21))
        p, d_old, d_new, used, tk, limit, h, t_now, y, stride, di = (
            args[i] for i in (1, 3, 4, 8, 9, 10, 11, 12, 16, 17, 19))
        nontemporal = builder.module.add_metadata([ir.Constant(ir.IntType(32), 1)])
        rint = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_V8, [_V8]), "llvm.rint.v8f64")
        i1v = ir.VectorType(ir.IntType(1), VEC)
        no = ir.Constant(_B8, [0] * VEC)
        none = ir.Constant(ir.IntType(VEC), 0)
        deferred = cgutils.alloca_once_value(builder, ir.Constant(_I64, 0))
        waiting = cgutils.alloca_once_value(builder, ir.Constant(_I64, 0))
        slots = [cgutils.alloca_once(builder, _V8) for _ in range(7)]     # state (3), NEXT, Gamma (3)
        missing, found = cgutils.alloca_once(builder, i1v), cgutils.alloca_once(builder, i1v)
        for v in range(LANES // VEC):
            at = ir.Constant(_I64, VEC * v)
            pe = [P.load(_at(builder, p, LANES * e + VEC * v)) for e in range(12)]
            x = [W.row(r, v) for r in (ROW_I, ROW_W, ROW_DELTA)]
            dq, U, nxt = W.row(d_old, v), W.row(ROW_U, v), W.row(ROW_NEXT, v)
            mine = builder.icmp_unsigned("!=", own.load(at, _B8), no)
            u = builder.select(mine, builder.fmul(dq, W.row(ROW_V, v)), U)
            for r in range(3):
                acc = builder.fadd(builder.fmul(pe[3 * r], x[0]), builder.fmul(pe[3 * r + 1], x[1]))
                acc = builder.fadd(acc, builder.fmul(pe[3 * r + 2], x[2]))
                builder.store(builder.fadd(acc, builder.fmul(pe[9 + r], u)), slots[r])
            builder.store(nxt, slots[3])
            builder.store(ir.Constant(i1v, [0] * VEC), missing)
            due = builder.fcmp_ordered("<", nxt, _splat(builder, limit))
            with builder.if_then(builder.icmp_unsigned("!=", builder.bitcast(due, ir.IntType(VEC)), none),
                                 likely=False):
                NV = W.row(ROW_NV, v)
                du = builder.fsub(NV, U)
                a = builder.fsub(nxt, _splat(builder, tk))
                key = builder.fdiv(builder.call(rint, [builder.fmul(builder.fsub(_splat(builder, h), a), _const(1e12))]),
                                   _const(1e12))
                for r in range(3):
                    builder.store(_const(0.0), slots[4 + r])
                builder.store(ir.Constant(i1v, [0] * VEC), found)
                with cgutils.for_range(builder, used) as loop:     # the slots in use only
                    hit = builder.fcmp_ordered("==", key, BK.row(loop.index, v))
                    builder.store(builder.or_(builder.load(found), hit), found)
                    row = builder.mul(loop.index, ir.Constant(_I64, 3))
                    for r in range(3):
                        g = BG.row(builder.add(row, ir.Constant(_I64, r)), v)
                        builder.store(builder.select(hit, g, builder.load(slots[4 + r])), slots[4 + r])
                at_start = builder.fcmp_ordered("<=", a, _const(TIME_EPS))
                g = [builder.select(at_start, P.load(_at(builder, p, (9 + r) * LANES + VEC * v)),
                                    builder.load(slots[4 + r])) for r in range(3)]
                moved = builder.fcmp_unordered("!=", du, _const(0.0))
                miss = builder.and_(builder.and_(due, moved), builder.not_(builder.or_(at_start, builder.load(found))))
                ok = builder.and_(due, builder.not_(miss))
                apply = builder.and_(ok, moved)
                for r in range(3):
                    e = builder.fadd(_const(0.0), builder.fmul(g[r], du))
                    xr = builder.load(slots[r])
                    builder.store(builder.select(apply, builder.fadd(xr, e), xr), slots[r])
                W.set_row(ROW_U, v, builder.select(ok, NV, U))
                landed = builder.select(ok, _const(np.inf), nxt)
                W.set_row(ROW_NEXT, v, landed)
                builder.store(landed, slots[3])
                builder.store(miss, missing)
            new = [builder.load(slots[r]) for r in range(3)]
            for r in range(3):
                W.set_row(r, v, new[r])
            nxt = builder.load(slots[3])
            miss = builder.load(missing)
            with builder.if_else(builder.icmp_unsigned("!=", builder.bitcast(miss, ir.IntType(VEC)), none),
                                 likely=False) as (unusual, usual):
                with unusual:                           # the caller finishes this vector
                    odd.store(at, builder.select(miss, ir.Constant(_B8, [1] * VEC), ir.Constant(_B8, [2] * VEC)),
                              _B8, align=1)
                    builder.store(builder.add(builder.load(deferred), ir.Constant(_I64, 1)), deferred)
                with usual:
                    flag = builder.uitofp(builder.fcmp_ordered(">=", builder.fmul(dq, new[2]), W.row(ROW_THR, v)), _V8)
                    dn = builder.fsub(dq, builder.fmul(builder.fmul(_const(2.0), dq), flag))
                    W.set_row(d_new, v, dn)
                    changed = builder.and_(builder.fcmp_unordered("!=", dq, dn), _mask_of(builder, queued, v))
                    with builder.if_then(builder.icmp_unsigned("!=", builder.bitcast(changed, ir.IntType(VEC)), none),
                                         likely=False):
                        free = builder.and_(builder.fcmp_ordered("==", nxt, _const(np.inf)),
                                            builder.not_(_mask_of(builder, ringed, v)))
                        simple = builder.and_(changed, free)
                        late = builder.and_(changed, builder.not_(free))
                        W.set_row(ROW_NEXT, v, builder.select(simple, builder.fadd(_splat(builder, t_now),
                                                                                   W.row(ROW_TD, v)), nxt))
                        W.set_row(ROW_NV, v, builder.select(simple, builder.fmul(dn, W.row(ROW_V, v)), W.row(ROW_NV, v)))
                        busy.store(at, builder.zext(late, _B8), _B8, align=1)
                        builder.store(builder.add(builder.load(waiting), _count(builder, late)), waiting)
                    for r in range(3):
                        o = builder.add(y, builder.add(builder.mul(stride, ir.Constant(_I64, r)), at))
                        Yr.store(o, new[r], align=8 * VEC).set_metadata("nontemporal", nontemporal)
                    out.store(builder.add(di, at), builder.fptosi(dn, _B8), _B8, align=1)
        return builder.add(builder.load(deferred), builder.shl(builder.load(waiting), ir.Constant(_I64, 32)))

    return sig, codegen


@njit(cache=True)
def guard_threshold(R: float, guard: float) -> float:
    """The least delta with delta / R >= guard in floating point (R, guard > 0).

    Division rounds monotonically, so for a command d = +-1 the sampled guard
    d * (delta / R) >= guard holds exactly when d * delta >= this threshold:
    the lanes decide without dividing, and theta = delta / R is formed only
    when asked for, with the same bits.
    """
    x = guard * R
    while x / R >= guard:
        x = np.nextafter(x, -np.inf)
    while x / R < guard:
        x = np.nextafter(x, np.inf)
    return x


@njit(cache=True)
def _window_sums(t, longest) -> np.ndarray:
    """Distinct rounded t[k + r] - t[k] (r >= 1) up to ``longest`` (+ one step): the spans from a decision
    to the end of the step its command can land in."""
    n = len(t)
    sums = np.empty(64)
    found = 0
    for r in range(1, n):
        any_short = False
        for k in range(n - r):
            w = step_key(t[k + r] - t[k])
            if w - (t[k + r] - t[k + r - 1]) > longest + TIME_EPS:
                continue
            any_short = True
            c = 0
            while c < found and sums[c] != w:
                c += 1
            if c == found:
                if found == len(sums):
                    return sums[:found]
                sums[found] = w
                found += 1
        if not any_short:
            break
    return sums[:found]


@njit(cache=True)
def _split_candidates(t, A, B, Td, undelayed, keys, gammas, n_split) -> None:
    """Fill every delayed set's split cache with Gamma(W - Td) for the spans W that can end its commands'
    steps (Td < W <= Td + a step), computed side by side (``phi_gamma_lanes``) before the loop.

    A head start only: ``_land`` finds them there, and ``_split_slot``
    computes any it misses (a key rounded the other way, a full cache) --
    the values are the same either way.
    """
    m = len(Td)
    longest = 0.0
    for q in range(m):
        if not undelayed[q]:
            longest = max(longest, Td[q])
    sums = _window_sums(t, longest)
    hmax = 0.0
    for k in range(len(t) - 1):
        hmax = max(hmax, t[k + 1] - t[k])
    sets = np.empty(m * MAX_SPLITS, dtype=np.int64)
    lengths = np.empty(m * MAX_SPLITS)
    count = 0
    for q in range(m):
        if undelayed[q]:
            continue
        for w in sums:
            if Td[q] + TIME_EPS < w <= Td[q] + hmax + TIME_EPS and n_split[q] < MAX_SPLITS:
                key = step_key(w - Td[q])
                keys[q, n_split[q]] = key
                n_split[q] += 1
                sets[count], lengths[count] = q, key
                count += 1
    out = np.empty((12, count))
    phi_gamma_lanes(A, B, sets[:count], lengths[:count], out)
    slot = np.zeros(m, dtype=np.int64)
    for i in range(count):
        q = sets[i]
        gammas[q, slot[q], 0], gammas[q, slot[q], 1], gammas[q, slot[q], 2] = out[9, i], out[10, i], out[11, i]
        slot[q] += 1


@intrinsic
def _store_fence(typingctx):
    """Order the non-temporal stores before anything after (they bypass the usual store ordering)."""
    sig = types.void()

    def codegen(context, builder, signature, args):
        builder.fence("seq_cst")
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True)
def _work_rows() -> np.ndarray:
    """(WORK_ROWS, LANES) float64 whose rows start on cache lines (a block's vectors, loaded whole)."""
    buf = np.empty(LANES * WORK_ROWS + VEC)
    off = ((-buf.ctypes.data) % (8 * VEC)) // 8
    return buf[off:off + LANES * WORK_ROWS].reshape(WORK_ROWS, LANES)


@njit(cache=True)
def _block_matrices(A, B, lengths, mp) -> np.ndarray:
    """(Phi, Gamma) of every set for every distinct length, laid out (block, length, entry, lane): a block's
    matrices are one contiguous run.  Lanes past the last set repeat it (their outputs are never read)."""
    m = A.shape[0]
    nlen = len(lengths)
    P = np.empty((mp // LANES, nlen * 12 * LANES))
    flat = np.empty((12, m))
    sets = np.arange(m)
    for j in range(nlen):
        phi_gamma_lanes(A, B, sets, np.full(m, lengths[j]), flat)
        for q in range(mp):
            src = min(q, m - 1)
            for e in range(12):
                P[q // LANES, (12 * j + e) * LANES + q % LANES] = flat[e, src]
    return P


@njit(cache=True)
def _queue_capacity(t, Td, undelayed) -> int:
    """The most commands one set can have on their way at once (+1): those decided within Td before a
    sample, for the longest delay of the batch."""
    longest = 0.0
    for q in range(len(Td)):
        if not undelayed[q]:
            longest = max(longest, Td[q])
    most, j = 1, 0
    for k in range(len(t)):
        while t[j] < t[k] - longest - 1e-6:          # generous: rounding may keep one more a while
            j += 1
        most = max(most, k - j + 1)
    return most + 2


@njit(cache=True, nogil=True)
def run_linear_lanes(t, A, B, R, guard, V, Td, x0, log, closed_loop, start, first, dir0, Y, dirs, col0) -> None:
    """The automaton for m sets, LANES at a time: fills Y = (current, omega, delta) (n, 3, mp), dirs (n, mp).

    A (m, 3, 3), B (m, 3); R, guard, V, Td (m,); the other arguments as
    ``kernels.run_linear_batch``.  mp is m rounded up to whole blocks (the
    columns past m are scratch) and Y must start on a cache line
    (``lane_outputs``).  theta = delta / R is left to the caller.
    """
    n, m = len(t), len(R)
    mp = Y.shape[2]
    blocks = -(-m // LANES)
    if (mp % LANES != 0 or col0 % LANES != 0 or col0 + LANES * blocks > mp or Y.ctypes.data % (8 * VEC) != 0
            or dirs.shape[1] != mp):
        raise ValueError("Y, dirs must be lane_outputs(...) with room for the sets from column col0")
    lengths, idx = step_lengths(t)
    P = _block_matrices(A, B, lengths, LANES * blocks)
    undelayed = np.empty(m, dtype=np.bool_)
    for q in range(m):
        undelayed[q] = closed_loop and Td[q] == 0.0
    keys, gammas, n_split = np.empty((m, MAX_SPLITS)), np.empty((m, MAX_SPLITS, 3)), np.zeros(m, dtype=np.int64)
    if not undelayed.all():
        _split_candidates(t, A, B, Td, undelayed, keys, gammas, n_split)
    cap = _queue_capacity(t, Td, undelayed)
    queues = (np.empty((LANES, cap)), np.empty((LANES, cap)), np.zeros(LANES, dtype=np.int64),
              np.zeros(LANES, dtype=np.int64), np.zeros(LANES, dtype=np.uint8), np.zeros(LANES, dtype=np.uint8))
    # a block's split caches: keys (slot, lane), Gammas (slot, row, lane), entries per lane, scratch
    splits = (keys, gammas, n_split, np.empty(MAX_SPLITS * LANES), np.empty(3 * MAX_SPLITS * LANES),
              np.zeros(LANES, dtype=np.int64), np.empty(12))
    W = _work_rows()
    own = np.empty(LANES, dtype=np.uint8)               # 1: the set's command acts at once (no queue)
    queued = np.empty(LANES, dtype=np.uint8)            # its complement
    flags = np.zeros(LANES, dtype=np.uint8)
    for b in range(blocks):
        _run_block(b, t, idx, P[b], A, B, R, guard, V, Td, x0, log, closed_loop, start, first, dir0, Y, dirs,
                   col0 + LANES * b, undelayed, W, own, queued, flags, queues, splits)
    _store_fence()


@njit(cache=True)
def _run_block(b, t, idx, Pb, A, B, R, guard, V, Td, x0, log, closed_loop, start, first, dir0, Y, dirs,
               out, undelayed, W, own, queued, flags, queues, splits) -> None:
    """Block b (sets LANES b ..., output columns out ...) through every sample."""
    n, m, mp = len(t), len(R), Y.shape[2]
    lo = LANES * b
    n_queued = 0
    for l in range(LANES):
        q = min(lo + l, m - 1)
        W[ROW_I, l], W[ROW_W, l], W[ROW_DELTA, l] = x0[0], x0[1], x0[2]
        W[ROW_U, l], W[ROW_V, l], W[ROW_THR, l] = 0.0, V[q], guard_threshold(R[q], guard[q])
        W[ROW_TD, l], W[ROW_NEXT, l], W[ROW_NV, l] = Td[q], np.inf, 0.0
        own[l] = 1 if undelayed[q] or lo + l >= m else 0      # padding lanes: no queue
        queued[l] = 1 - own[l]
        n_queued += queued[l]
        W[ROW_D1, l] = decide(0, 0, x0[2] / R[q], guard[q], log, closed_loop, start, first, dir0)
    if n_queued:
        arrive, volts, head, count, ringed, busy = queues
        keys, gammas, n_split, BK, BG, bn, G = splits
        for l in range(LANES):                          # the block's split caches (empty slots: NaN keys)
            q = min(lo + l, m - 1)
            bn[l] = n_split[q] if queued[l] else 0
            head[l] = count[l] = ringed[l] = 0
            for c in range(MAX_SPLITS):
                BK[c * LANES + l] = keys[q, c] if c < bn[l] else np.nan
                for r in range(3):
                    BG[(3 * c + r) * LANES + l] = gammas[q, c, r] if c < bn[l] else 0.0
        _queued_run(t, idx, Pb, A, B, R, guard, Td, log, closed_loop, start, first, dir0, Y, dirs, lo, out, W, own,
                    queued, flags, busy, arrive, volts, head, count, ringed, BK, BG, bn, G)
        return
    d_old, d_new = ROW_D0, ROW_D1
    for k in range(n):
        if closed_loop and k > start:                   # nothing left but the sampled guard
            _free_run(k, n, Pb, idx, W, d_old, Y, dirs, out, mp)
            return
        if k > 0:
            _step(Pb, 12 * LANES * idx[k - 1], W, d_old)
            _decide_block(k, W, d_old, d_new, lo, R, guard, log, closed_loop, start, first, dir0)
        _emit(Y, 3 * mp * k + out, mp, W, dirs, mp * k + out, d_new)
        d_old, d_new = d_new, d_old


@njit(cache=True)
def _decide_block(k, W, d_old, d_new, lo, R, guard, log, closed_loop, start, first, dir0) -> None:
    """Every command of the block at sample k > 0 (``kernels.decide``; the sampled guard as ``_flip``)."""
    m = len(R)
    if not closed_loop or k < start:
        for l in range(LANES):
            W[d_new, l] = log[k]
    elif k == start:
        for l in range(LANES):
            q = min(lo + l, m - 1)
            W[d_new, l] = decide(k, int(W[d_old, l]), W[ROW_DELTA, l] / R[q], guard[q], log, closed_loop,
                                 start, first, dir0)
    else:
        _flip(W, d_old, d_new)


@njit(cache=True)
def _free_run(k0, n, Pb, idx, W, d_old, Y, dirs, out, mp) -> None:
    """Samples k0.. of a block with no queue, in closed loop past the controller's start: step, guard,
    outputs (to columns out ...)."""
    stride = 12 * LANES
    d_new = ROW_D0 + ROW_D1 - d_old
    for k in range(k0, n):
        _advance(Pb, stride * idx[k - 1], W, d_old, d_new, Y, 3 * mp * k + out, mp, dirs, mp * k + out)
        d_old, d_new = d_new, d_old


@njit(cache=True)
def _queued_run(t, idx, Pb, A, B, R, guard, Td, log, closed_loop, start, first, dir0, Y, dirs, lo, out, W, own,
                queued, flags, busy, arrive, volts, head, count, ringed, BK, BG, bn, G) -> None:
    """A block with delayed sets through every sample: their commands travel Td and land inside the step they
    reach the motor in (``kernels._delayed``'s queue).

    One command on its way per set is the rule (commands are many samples
    apart) and is handled in vector rows: past the controller's start in
    closed loop by one pass per sample (``_queued_free_run``), otherwise by
    ``_step_motor``, ``_land``, the decision and ``_send``.  A set with more
    on their way moves to a ring (``arrive``, ``volts``; ``ringed``, its
    vector row then empty) handled here set by set, as is a split length a
    set's cache lacks.  Written out in one function: helpers taking these
    arrays cost a reference count per array and call, more than their work.
    """
    n, mp = len(t), Y.shape[2]
    cap = arrive.shape[1]
    for l in range(LANES):
        W[ROW_D0, l] = np.nan                           # at sample 0 every delayed set sends its command
    ring_next = np.inf                                  # earliest arrival in the rings
    used = 0                                            # split cache slots any set has filled
    for l in range(LANES):
        used = max(used, bn[l])
    odd = np.zeros(LANES, dtype=np.uint8)
    k = 0
    while k < n:
        if closed_loop and k > start:                   # the usual samples: one pass each (``_queued_free_run``)
            k, done = _queued_free_run(k, n, t, idx, Pb, W, own, BK, BG, used, queued, ringed, Y, dirs, out, odd,
                                       busy, ring_next)
            if k == n:
                break
        else:
            done = 0
        d_old, d_new = ROW_D0 + (k & 1), ROW_D1 - (k & 1)   # the command rows alternate
        if done:                                        # sample k is stepped but needs work set by set
            j = idx[k - 1]
            tk, t_next = t[k - 1], t[k]
            if done & 0xFFFFFFFF:                       # vectors with a split length to compute
                for l in range(LANES):
                    if not odd[l]:
                        continue
                    if odd[l] == 1:                     # its command lands (as below)
                        du = W[ROW_NV, l] - W[ROW_U, l]
                        W[ROW_U, l] = W[ROW_NV, l]
                        a = W[ROW_NEXT, l] - tk
                        W[ROW_NEXT, l] = np.inf
                        s = _split_slot(l, lo + l, step_key((t_next - tk) - a), A, B, BK, BG, bn, G)
                        used = max(used, s + 1)
                        e0 = 0.0 + BG[(3 * s) * LANES + l] * du
                        e1 = 0.0 + BG[(3 * s + 1) * LANES + l] * du
                        e2 = 0.0 + BG[(3 * s + 2) * LANES + l] * du
                        W[ROW_I, l] += e0
                        W[ROW_W, l] += e1
                        W[ROW_DELTA, l] += e2
                    dq = W[d_old, l]                    # ``_flip``, ``_send`` and ``_emit`` for this set
                    dn = dq - 2.0 * dq * (dq * W[ROW_DELTA, l] >= W[ROW_THR, l])
                    W[d_new, l] = dn
                    if dn != dq and queued[l]:
                        if W[ROW_NEXT, l] == np.inf and not ringed[l]:
                            W[ROW_NEXT, l], W[ROW_NV, l] = t_next + W[ROW_TD, l], dn * W[ROW_V, l]
                        else:
                            busy[l] = 1
                            done += 1 << 32
                    Y[k, 0, out + l], Y[k, 1, out + l], Y[k, 2, out + l] = W[ROW_I, l], W[ROW_W, l], W[ROW_DELTA, l]
                    dirs[k, out + l] = np.int8(dn)
                    odd[l] = 0
            if done >> 32:
                for l in range(LANES):
                    if busy[l]:
                        _to_ring(l, t_next + Td[lo + l], W[d_new, l] * W[ROW_V, l], W, arrive, volts, head, count,
                                 ringed)
                        busy[l] = 0
                ring_next = _ring_next(arrive, head, ringed)
            k += 1
            continue
        if k > 0:
            j = idx[k - 1]
            _step_motor(Pb, 12 * LANES * j, W, d_old, own)
            tk, t_next = t[k - 1], t[k]
            h = t_next - tk
            limit = t_next - TIME_EPS
            missed = _land(W, Pb, 12 * LANES * j, BK, BG, tk, limit, h, flags)
            if missed or ring_next < limit:             # the rest, one set at a time
                for l in range(LANES):
                    if not (flags[l] or ringed[l] and arrive[l, head[l]] < limit):
                        continue
                    q = lo + l
                    e0 = e1 = e2 = 0.0
                    moved = False
                    if ringed[l]:
                        c = head[l]
                        while count[l] > 0 and arrive[l, c] < limit:
                            du = volts[l, c] - W[ROW_U, l]
                            W[ROW_U, l] = volts[l, c]
                            a = arrive[l, c] - tk
                            c = c + 1 if c + 1 < cap else 0
                            count[l] -= 1
                            if du != 0.0:
                                moved = True
                                if a <= TIME_EPS:
                                    e0 += Pb[(12 * j + 9) * LANES + l] * du
                                    e1 += Pb[(12 * j + 10) * LANES + l] * du
                                    e2 += Pb[(12 * j + 11) * LANES + l] * du
                                else:
                                    s = _split_slot(l, q, step_key(h - a), A, B, BK, BG, bn, G)
                                    used = max(used, s + 1)
                                    e0 += BG[(3 * s) * LANES + l] * du
                                    e1 += BG[(3 * s + 1) * LANES + l] * du
                                    e2 += BG[(3 * s + 2) * LANES + l] * du
                        head[l] = c
                        ringed[l] = count[l] > 0        # empty: back to the vector rows
                    else:                               # one command, a split length not in the cache
                        du = W[ROW_NV, l] - W[ROW_U, l]
                        W[ROW_U, l] = W[ROW_NV, l]
                        a = W[ROW_NEXT, l] - tk
                        W[ROW_NEXT, l] = np.inf
                        moved = True
                        s = _split_slot(l, q, step_key(h - a), A, B, BK, BG, bn, G)
                        used = max(used, s + 1)
                        e0 += BG[(3 * s) * LANES + l] * du
                        e1 += BG[(3 * s + 1) * LANES + l] * du
                        e2 += BG[(3 * s + 2) * LANES + l] * du
                    if moved:
                        W[ROW_I, l] += e0
                        W[ROW_W, l] += e1
                        W[ROW_DELTA, l] += e2
                ring_next = _ring_next(arrive, head, ringed)
            if closed_loop and k > start:
                _flip(W, d_old, d_new)
            elif not closed_loop or k < start:
                _fill(W, d_new, log[k])
            else:
                _decide_block(k, W, d_old, d_new, lo, R, guard, log, closed_loop, start, first, dir0)
        if _send(W, d_old, d_new, t[k], queued, ringed, flags):  # sets with a command already on its way
            for l in range(LANES):
                if flags[l]:
                    _to_ring(l, t[k] + Td[lo + l], W[d_new, l] * W[ROW_V, l], W, arrive, volts, head, count, ringed)
            ring_next = _ring_next(arrive, head, ringed)
        _emit(Y, 3 * mp * k + out, mp, W, dirs, mp * k + out, d_new)
        k += 1


@njit(cache=True)
def _queued_free_run(k, n, t, idx, Pb, W, own, BK, BG, used, queued, ringed, Y, dirs, out, odd, busy, ring_next):
    """Samples k.. of a block with delayed sets, in closed loop past the controller's start, each in one pass
    (``_advance_queued``) until one needs work set by set: returns that sample and its flags (0: a ring's
    command lands there, not stepped yet), or n.  The rare paths are the caller's."""
    mp = Y.shape[2]
    while k < n:
        tk, t_next = t[k - 1], t[k]
        if ring_next < t_next - TIME_EPS:
            return k, 0
        done = _advance_queued(Pb, 12 * LANES * idx[k - 1], W, ROW_D0 + (k & 1), ROW_D1 - (k & 1), own, BK, BG,
                               used, tk, t_next - TIME_EPS, t_next - tk, t_next, queued, ringed, Y, 3 * mp * k + out,
                               mp, dirs, mp * k + out, odd, busy)
        if done:
            return k, done
        k += 1
    return k, 0


@njit(cache=True)
def _to_ring(l, arrival, volt, W, arrive, volts, head, count, ringed) -> None:
    """Queue a command for set l behind those on their way: in its ring (the vector rows' command, if any,
    moves there first)."""
    cap = arrive.shape[1]
    if not ringed[l]:
        arrive[l, head[l]], volts[l, head[l]] = W[ROW_NEXT, l], W[ROW_NV, l]
        count[l] = 1
        ringed[l] = 1
        W[ROW_NEXT, l] = np.inf
    c = head[l] + count[l]
    c = c - cap if c >= cap else c
    arrive[l, c] = arrival
    volts[l, c] = volt
    count[l] += 1


@njit(cache=True)
def _ring_next(arrive, head, ringed) -> float:
    """The earliest arrival among the rings (a set's ring is in order: its head)."""
    soonest = np.inf
    for l in range(LANES):
        if ringed[l]:
            soonest = min(soonest, arrive[l, head[l]])
    return soonest


@njit(cache=True)
def _split_slot(l, q, key, A, B, BK, BG, bn, G) -> int:
    """The slot of Gamma(key) in lane l's split cache (set q), computed there if missing (as
    ``kernels._delayed``: a full cache starts over at slot 0)."""
    for c in range(MAX_SPLITS):
        if BK[c * LANES + l] == key:
            return c
    c = bn[l]
    if c == MAX_SPLITS:
        c = bn[l] = 0
    phi_gamma_into(A[q], B[q], key, G)
    BK[c * LANES + l] = key
    BG[(3 * c) * LANES + l], BG[(3 * c + 1) * LANES + l], BG[(3 * c + 2) * LANES + l] = G[9], G[10], G[11]
    bn[l] += 1
    return c


class _Recycled:
    """The last batch's output memory, handed out again once no result refers to it.

    1000 sets x 500 samples are 12.5 MB: a fresh block costs its first touch
    (page faults and the kernel zeroing huge pages, ~2.5 ms here, twice the
    simulation) every time the allocator hands out new pages, which it does
    whenever other work has used the freed block in between.  A fitting loop
    drops each result before the next batch, so its batches reuse one block.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._raw: np.ndarray | None = None

    def take(self, nbytes: int) -> np.ndarray:
        with self._lock:
            raw, self._raw = self._raw, None
        # refcount 2: this name and getrefcount's argument -- no result's arrays (views of raw) are alive
        if raw is not None and nbytes <= raw.size <= 2 * nbytes and sys.getrefcount(raw) == 2:
            return raw
        return np.empty(nbytes, dtype=np.uint8)

    def keep(self, raw: np.ndarray) -> None:
        with self._lock:
            self._raw = raw


_recycled = _Recycled()


def lane_outputs(m: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Outputs for ``run_linear_lanes``: current, omega, delta as one (n, 3, mp) float block starting on a cache
    line (mp: m rounded up to whole blocks) and dirs (n, mp) int8, both views of one recycled block of memory
    (``_Recycled``)."""
    mp = LANES * max(1, -(-m // LANES))
    floats = 8 * 3 * mp * n
    raw = _recycled.take(floats + mp * n + 8 * VEC)
    off = -raw.ctypes.data % (8 * VEC)
    Y = raw[off:off + floats].view(np.float64).reshape(n, 3, mp)
    dirs = raw[off + floats:off + floats + mp * n].reshape(n, mp)
    _recycled.keep(raw)
    return Y, dirs.view(np.int8)
