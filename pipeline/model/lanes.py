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
  of the step (``block_ir.step``), and the sampled guard is a sign flip when
  d * delta >= ``guard_threshold`` (``flip``: no division, a select); the
  block's eight-set vectors are independent, so their chains overlap;
- a delayed set's command travels in two vector rows (arrival, volts) and
  lands inside the step it reaches the motor in, adding ``kernels._delayed``'s
  correction ``Gamma(h - a) du`` (``send``, ``land``); the rare set with
  several commands on their way, or a split length its cache lacks, is
  handled one set at a time;
- past the controller's start in closed loop, each sample is one pass over
  the block's vectors (``advance``, ``advance_queued``): a vector's outputs
  leave, as whole 64-byte lines by non-temporal stores, right after it is
  computed, so the 12.5 MB of 1000 sets x 500 samples stream out while the
  arithmetic goes on (writing them after each step, or with ordinary stores
  that read every line first, cost as much again);
- a block's rows sit at a fixed offset from the outputs' address modulo
  4 KiB (``_lines``), and threads claim whole blocks from either end of the
  batch (``run_linear_lanes``).

Per set the operations and their order are those of ``kernels`` (the common
part is the first four terms of its sum, the correction the fifth), so a batch
equals the single calls to the last bit (tests/model/test_batch.py).
"""

from __future__ import annotations

import sys
import threading

import numpy as np
from numba import njit

from pipeline.model.block_ir import (LANES, MAX_SPLITS, ROW_D0, ROW_D1, ROW_DELTA, ROW_I, ROW_NEXT, ROW_NV, ROW_TD,
                                     ROW_THR, ROW_U, ROW_V, ROW_W, STEP_ENTRIES, VEC, WORK_ROWS, advance,
                                     advance_queued, claim, emit, fill, flip, land, send, step, step_motor,
                                     store_fence)
from pipeline.model.kernels import TIME_EPS, decide
from pipeline.model.linear import phi_gamma_into, phi_gamma_lanes, step_key, step_lengths

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
def _split_candidates(t, A, B, Td, undelayed, lo, sums, hmax, BK, BG, bn) -> None:
    """Fill the split caches of block lo.. (its delayed sets) with Gamma(W - Td) for the spans W in ``sums``
    (``_window_sums``) that can end their commands' steps (Td < W <= Td + hmax, the longest step),
    computed side by side (``phi_gamma_lanes``) before the block runs.

    The caches are laid out as ``land`` reads them: BK (slot x LANES + lane)
    keys, NaN where empty; BG ((3 slot + row) x LANES + lane) Gammas; bn
    (lane) entries.  A head start only: ``_split_slot`` computes any length
    missed (a key rounded the other way, a full cache) -- the values are the
    same either way.
    """
    m = len(Td)
    BK[:] = np.nan
    bn[:] = 0
    sets = np.empty(LANES * MAX_SPLITS, dtype=np.int64)
    lengths = np.empty(LANES * MAX_SPLITS)
    count = 0
    for l in range(min(LANES, m - lo)):
        q = lo + l
        if undelayed[q]:
            continue
        for w in sums:
            if Td[q] + TIME_EPS < w <= Td[q] + hmax + TIME_EPS and bn[l] < MAX_SPLITS:
                key = step_key(w - Td[q])
                BK[bn[l] * LANES + l] = key
                bn[l] += 1
                sets[count], lengths[count] = q, key
                count += 1
    out = np.empty((12, count))
    phi_gamma_lanes(A, B, sets[:count], lengths[:count], out)
    slot = np.zeros(LANES, dtype=np.int64)
    for i in range(count):
        l = sets[i] - lo
        c = slot[l]
        BG[(3 * c) * LANES + l], BG[(3 * c + 1) * LANES + l], BG[(3 * c + 2) * LANES + l] = (
            out[9, i], out[10, i], out[11, i])
        slot[l] += 1


@njit(cache=True)
def _lines(size, y) -> np.ndarray:
    """float64 (size,) for a block's rows of eight-set vectors: starting on a cache line (a vector then loads
    whole), two lines past the output address y modulo 4 KiB.

    A load whose address has a recent store's low 12 bits waits for it (4K
    aliasing): a vector's outputs are stored just before the next vector
    loads its rows, which are 512 bytes apart, so their phase against the
    outputs' matters.  Measured, one thread, delayed batch: rows one line
    before the outputs' phase 1.5 ms, two lines past it 1.09 ms; numba's
    allocations are 32-byte aligned, so the phase used to be a draw.
    """
    buf = np.empty(size + 4096 // 8)
    off = ((y + 2 * 64 - buf.ctypes.data) % 4096) // 8
    return buf[off:off + size]


@njit(cache=True)
def _work_rows(y) -> np.ndarray:
    """(WORK_ROWS, LANES) float64 whose rows are placed by ``_lines``."""
    return _lines(LANES * WORK_ROWS, y).reshape(WORK_ROWS, LANES)


@njit(cache=True)
def _block_matrices(A, B, lengths, lo, Pb) -> None:
    """(Phi, Gamma) of block lo..'s sets for every distinct length into Pb, laid out (length, entry, lane).
    Lanes past the last set copy it (their outputs are never read)."""
    nlen, w = len(lengths), min(LANES, A.shape[0] - lo)
    sets = np.empty(nlen * w, dtype=np.int64)
    h = np.empty(nlen * w)
    for j in range(nlen):
        for l in range(w):
            sets[j * w + l], h[j * w + l] = lo + l, lengths[j]
    flat = np.empty((12, nlen * w))
    phi_gamma_lanes(A, B, sets, h, flat)
    for j in range(nlen):
        for e in range(12):
            for l in range(LANES):
                Pb[(12 * j + e) * LANES + l] = flat[e, j * w + min(l, w - 1)]


@njit(cache=True)
def _queue_capacity(t, longest) -> int:
    """The most commands one set can have on their way at once (+1): those decided within ``longest``, the
    batch's longest loop delay, before a sample."""
    most, j = 1, 0
    for k in range(len(t)):
        while t[j] < t[k] - longest - 1e-6:          # generous: rounding may keep one more a while
            j += 1
        most = max(most, k - j + 1)
    return most + 2


@njit(cache=True, nogil=True)
def run_linear_lanes(t, A, B, R, guard, V, Td, x0, log, closed_loop, start, first, dir0, Y, dirs, next_block,
                     from_front) -> None:
    """The automaton for m sets, LANES at a time: fills Y = (current, omega, delta) (n, 3, mp) and dirs
    (n, mp), from ``lane_outputs`` (the columns past the last set, up to a whole block, are scratch).

    A (m, 3, 3), B (m, 3); R, guard, V, Td (m,); the other arguments as
    ``kernels.run_linear_batch``.  Releases the GIL: threads sharing one
    ``next_block`` (int64[3], zeros: blocks claimed, from the front, from
    the back) run one batch together.  Each claims the next block left at
    its end (``from_front`` or the back: each thread's outputs stay
    contiguous; blocks dealt alternately measured 7 % slower on two) and
    computes that block's step matrices and split caches itself, so a
    thread that starts late, or runs on a busy core, takes fewer blocks.
    theta = delta / R is left to the caller.
    """
    n, m = len(t), len(R)
    mp = Y.shape[2]
    blocks = -(-m // LANES)
    if (mp % LANES != 0 or LANES * blocks > mp or Y.ctypes.data % (8 * VEC) != 0 or dirs.shape[1] != mp
            or len(next_block) != 3):
        raise ValueError("Y, dirs must be lane_outputs(...) for the sets and next_block three counters")
    lengths, idx = step_lengths(t)
    undelayed = np.empty(m, dtype=np.bool_)
    longest = 0.0                                       # the longest loop delay
    for q in range(m):
        undelayed[q] = closed_loop and Td[q] == 0.0
        if not undelayed[q]:
            longest = max(longest, Td[q])
    sums = _window_sums(t, longest)
    hmax = 0.0
    for k in range(n - 1):
        hmax = max(hmax, t[k + 1] - t[k])
    y = Y.ctypes.data
    Pb = _lines(len(lengths) * STEP_ENTRIES, y)         # the block's step matrices (``_block_matrices``)
    BK = _lines(MAX_SPLITS * LANES, y)                  # its split caches (``_split_candidates``)
    BG = _lines(3 * MAX_SPLITS * LANES, y)
    bn = np.zeros(LANES, dtype=np.int64)
    cap = _queue_capacity(t, longest)
    queues = (np.empty((LANES, cap)), np.empty((LANES, cap)), np.zeros(LANES, dtype=np.int64),
              np.zeros(LANES, dtype=np.int64), np.zeros(LANES, dtype=np.uint8), np.zeros(LANES, dtype=np.uint8))
    G = np.empty(12)
    W = _work_rows(y)
    own = np.empty(LANES, dtype=np.uint8)               # 1: the set's command acts at once (0: it has a queue)
    flags = np.zeros(LANES, dtype=np.uint8)
    while claim(next_block, 0) < blocks:               # a block is left: the next from this thread's end
        b = claim(next_block, 1) if from_front else blocks - 1 - claim(next_block, 2)
        _block_matrices(A, B, lengths, LANES * b, Pb)
        _run_block(LANES * b, t, idx, Pb, A, B, R, guard, V, Td, x0, log, closed_loop, start, first, dir0, Y, dirs,
                   undelayed, sums, hmax, W, own, flags, queues, BK, BG, bn, G)
    store_fence()


@njit(cache=True)
def _run_block(lo, t, idx, Pb, A, B, R, guard, V, Td, x0, log, closed_loop, start, first, dir0, Y, dirs,
               undelayed, sums, hmax, W, own, flags, queues, BK, BG, bn, G) -> None:
    """The block of sets lo ... (output columns lo ...) through every sample."""
    n, m, mp = len(t), len(R), Y.shape[2]
    n_queued = 0
    for l in range(LANES):
        q = min(lo + l, m - 1)
        W[ROW_I, l], W[ROW_W, l], W[ROW_DELTA, l] = x0[0], x0[1], x0[2]
        W[ROW_U, l], W[ROW_V, l], W[ROW_THR, l] = 0.0, V[q], guard_threshold(R[q], guard[q])
        W[ROW_TD, l], W[ROW_NEXT, l], W[ROW_NV, l] = Td[q], np.inf, 0.0
        own[l] = 1 if undelayed[q] or lo + l >= m else 0      # padding lanes: no queue
        n_queued += 1 - own[l]
        W[_command_rows(0)[1], l] = decide(0, 0, x0[2] / R[q], guard[q], log, closed_loop, start, first, dir0)
    if n_queued:
        _split_candidates(t, A, B, Td, undelayed, lo, sums, hmax, BK, BG, bn)
        arrive, volts, head, count, ringed, busy = queues
        for l in range(LANES):
            head[l] = count[l] = ringed[l] = 0
        _queued_run(t, idx, Pb, A, B, R, guard, Td, log, closed_loop, start, first, dir0, Y, dirs, lo, W, own,
                    flags, busy, arrive, volts, head, count, ringed, BK, BG, bn, G)
        return
    for k in range(n):
        if closed_loop and k > start:                   # nothing left but the sampled guard
            _free_run(k, n, Pb, idx, W, Y, dirs, lo, mp)
            return
        d_old, d_new = _command_rows(k)
        if k > 0:
            step(Pb, STEP_ENTRIES * idx[k - 1], W, d_old)
            _decide_block(k, W, d_old, d_new, lo, R, guard, log, closed_loop, start, first, dir0)
        emit(Y, 3 * mp * k + lo, mp, W, dirs, mp * k + lo, d_new)


@njit(cache=True, inline="always")
def _command_rows(k):
    """The work rows of the command before and at sample k (they alternate)."""
    return ROW_D0 + (k & 1), ROW_D1 - (k & 1)


@njit(cache=True)
def _decide_block(k, W, d_old, d_new, lo, R, guard, log, closed_loop, start, first, dir0) -> None:
    """Every command of the block at sample k > 0 (``kernels.decide``; the sampled guard as ``flip``)."""
    m = len(R)
    if not closed_loop or k < start:
        fill(W, d_new, log[k])
    elif k == start:
        for l in range(LANES):
            q = min(lo + l, m - 1)
            W[d_new, l] = decide(k, int(W[d_old, l]), W[ROW_DELTA, l] / R[q], guard[q], log, closed_loop,
                                 start, first, dir0)
    else:
        flip(W, d_old, d_new)


@njit(cache=True)
def _free_run(k0, n, Pb, idx, W, Y, dirs, out, mp) -> None:
    """Samples k0.. of a block with no queue, in closed loop past the controller's start: step, guard,
    outputs (to columns out ...)."""
    for k in range(k0, n):
        d_old, d_new = _command_rows(k)
        advance(Pb, STEP_ENTRIES * idx[k - 1], W, d_old, d_new, Y, 3 * mp * k + out, mp, dirs, mp * k + out)


@njit(cache=True)
def _queued_run(t, idx, Pb, A, B, R, guard, Td, log, closed_loop, start, first, dir0, Y, dirs, lo, W, own,
                flags, busy, arrive, volts, head, count, ringed, BK, BG, bn, G) -> None:
    """A block with delayed sets through every sample: their commands travel Td and land inside the step they
    reach the motor in (``kernels._delayed``'s queue).

    One command on its way per set is the rule (commands are many samples
    apart) and is handled in vector rows: past the controller's start in
    closed loop by one pass per sample (``_queued_free_run``), otherwise by
    ``step_motor``, ``land``, the decision and ``send``.  A set with more
    on their way moves to a ring (``arrive``, ``volts``; ``ringed``, its
    vector row then empty) handled here set by set, as is a split length a
    set's cache lacks.  Written out in one function: helpers taking these
    arrays cost a reference count per array and call, more than their work.
    """
    n, mp = len(t), Y.shape[2]
    cap = arrive.shape[1]
    for l in range(LANES):
        W[_command_rows(0)[0], l] = np.nan              # at sample 0 every delayed set sends its command
    ring_next = np.inf                                  # earliest arrival in the rings
    used = 0                                            # split cache slots any set has filled
    for l in range(LANES):
        used = max(used, bn[l])
    odd = np.zeros(LANES, dtype=np.uint8)
    k = 0
    while k < n:
        if closed_loop and k > start:                   # the usual samples: one pass each (``_queued_free_run``)
            k, done = _queued_free_run(k, n, t, idx, Pb, W, own, BK, BG, used, ringed, Y, dirs, lo, odd, busy,
                                       ring_next)
            if k == n:
                break
        else:
            done = 0
        d_old, d_new = _command_rows(k)
        if done:                                        # sample k is stepped but needs work set by set
            j = idx[k - 1]
            tk, t_next = t[k - 1], t[k]
            if done & 0xFFFFFFFF:                       # vectors with a split length to compute
                for l in range(LANES):
                    if not odd[l]:
                        continue
                    if odd[l] == 1:                     # its command lands, its split length computed
                        used = max(used, _land_missed(l, lo + l, tk, t_next - tk, A, B, W, BK, BG, bn, G) + 1)
                    dq = W[d_old, l]                    # ``flip``, ``send`` and ``emit`` for this set
                    dn = -dq if dq * W[ROW_DELTA, l] >= W[ROW_THR, l] else dq
                    W[d_new, l] = dn
                    if dn != dq and not own[l]:
                        if W[ROW_NEXT, l] == np.inf and not ringed[l]:
                            W[ROW_NEXT, l], W[ROW_NV, l] = t_next + W[ROW_TD, l], dn * W[ROW_V, l]
                        else:
                            busy[l] = 1
                            done += 1 << 32
                    Y[k, 0, lo + l], Y[k, 1, lo + l], Y[k, 2, lo + l] = W[ROW_I, l], W[ROW_W, l], W[ROW_DELTA, l]
                    dirs[k, lo + l] = np.int8(dn)
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
            step_motor(Pb, STEP_ENTRIES * j, W, d_old, own)
            tk, t_next = t[k - 1], t[k]
            h = t_next - tk
            limit = t_next - TIME_EPS
            missed = land(W, Pb, STEP_ENTRIES * j, BK, BG, used, tk, limit, h, flags)
            if missed or ring_next < limit:             # the rest, one set at a time
                for l in range(LANES):
                    if not (flags[l] or ringed[l] and arrive[l, head[l]] < limit):
                        continue
                    q = lo + l
                    if ringed[l]:
                        e0 = e1 = e2 = 0.0
                        moved = False
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
                        if moved:
                            W[ROW_I, l] += e0
                            W[ROW_W, l] += e1
                            W[ROW_DELTA, l] += e2
                    else:                               # one command, a split length not in the cache
                        used = max(used, _land_missed(l, q, tk, h, A, B, W, BK, BG, bn, G) + 1)
                ring_next = _ring_next(arrive, head, ringed)
            if closed_loop and k > start:
                flip(W, d_old, d_new)
            elif not closed_loop or k < start:
                fill(W, d_new, log[k])
            else:
                _decide_block(k, W, d_old, d_new, lo, R, guard, log, closed_loop, start, first, dir0)
        if send(W, d_old, d_new, t[k], own, ringed, flags):  # sets with a command already on its way
            for l in range(LANES):
                if flags[l]:
                    _to_ring(l, t[k] + Td[lo + l], W[d_new, l] * W[ROW_V, l], W, arrive, volts, head, count, ringed)
            ring_next = _ring_next(arrive, head, ringed)
        emit(Y, 3 * mp * k + lo, mp, W, dirs, mp * k + lo, d_new)
        k += 1


@njit(cache=True)
def _queued_free_run(k, n, t, idx, Pb, W, own, BK, BG, used, ringed, Y, dirs, out, odd, busy, ring_next):
    """Samples k.. of a block with delayed sets, in closed loop past the controller's start, each in one pass
    (``advance_queued``) until one needs work set by set: returns that sample and its flags (0: a ring's
    command lands there, not stepped yet), or n.  The rare paths are the caller's."""
    mp = Y.shape[2]
    while k < n:
        tk, t_next = t[k - 1], t[k]
        if ring_next < t_next - TIME_EPS:
            return k, 0
        d_old, d_new = _command_rows(k)
        done = advance_queued(Pb, STEP_ENTRIES * idx[k - 1], W, d_old, d_new, own, BK, BG, used, tk,
                              t_next - TIME_EPS, t_next - tk, t_next, ringed, Y, 3 * mp * k + out, mp, dirs,
                              mp * k + out, odd, busy)
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
def _land_missed(l, q, tk, h, A, B, W, BK, BG, bn, G) -> int:
    """Set l's command on its way (vector rows) lands in the step from tk (length h) with a split length its
    cache lacks: ``land``'s arithmetic, one set, the Gamma computed (``_split_slot``); returns its slot."""
    du = W[ROW_NV, l] - W[ROW_U, l]
    W[ROW_U, l] = W[ROW_NV, l]
    a = W[ROW_NEXT, l] - tk
    W[ROW_NEXT, l] = np.inf
    s = _split_slot(l, q, step_key(h - a), A, B, BK, BG, bn, G)
    W[ROW_I, l] += 0.0 + BG[(3 * s) * LANES + l] * du
    W[ROW_W, l] += 0.0 + BG[(3 * s + 1) * LANES + l] * du
    W[ROW_DELTA, l] += 0.0 + BG[(3 * s + 2) * LANES + l] * du
    return s


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
