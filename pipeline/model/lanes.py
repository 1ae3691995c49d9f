"""Many parameter sets side by side (``simulate_batch``): the automaton of ``kernels`` laid out in lanes, compiled.

``kernels.run_linear_batch`` follows one set sample by sample: each step waits
on the previous one (a chain of multiply-adds), so a thousand sets cost a
thousand chains.  Here the sample loop is outside and the sets are inside, so
the sets fill the pipeline and LLVM turns the set loop into AVX arithmetic:

- every set's state moves by its own step matrices with the motor voltage it
  had at the start of the step (the common part, vectorised);
- a set whose delayed command reaches its motor inside the step gets the
  ``kernels._delayed`` correction ``Gamma(h - a) du`` added afterwards (few
  steps: commands change a few dozen times per recording);
- the sampled guard past the controller's start is a sign flip when
  d * delta >= ``guard_threshold`` (no division, a select).

Per set the operations and their order are those of ``kernels`` (the common
part is the first four terms of its sum, the correction the fifth), so a batch
equals the single calls to the last bit (tests/model/test_batch.py).

The outputs of 1000 sets x 500 samples are 12 MB: written with ordinary stores
they cost more than the arithmetic (each line is read before it is written).
The state lives in a small buffer the caches keep, and each sample's row is
copied out with non-temporal stores (``stream_copy``).
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic
from numba.np.arrayobj import make_array

from pipeline.model.kernels import TIME_EPS, decide
from pipeline.model.linear import phi_gamma_into, phi_gamma_lanes, step_key, step_lengths

# Gamma(h - a) remembered per set (split lengths of a fixed Td: a few).
MAX_SPLITS = 8
# Bytes of one non-temporal store (an AVX register): the alignment it needs.
STREAM_BYTES = 32


@intrinsic
def _stream4(typingctx, dst, i, src, j):
    """dst[i:i+4] = src[j:j+4] as one non-temporal 32-byte store (dst + i must be 32-byte aligned)."""
    sig = types.void(dst, types.intp, src, types.intp)

    def codegen(context, builder, signature, args):
        d = make_array(signature.args[0])(context, builder, args[0])
        s = make_array(signature.args[2])(context, builder, args[2])
        vec = ir.VectorType(ir.DoubleType(), 4)
        value = builder.load(builder.bitcast(builder.gep(s.data, [args[3]]), vec.as_pointer()), align=8)
        store = builder.store(value, builder.bitcast(builder.gep(d.data, [args[1]]), vec.as_pointer()),
                              align=STREAM_BYTES)
        store.set_metadata("nontemporal", builder.module.add_metadata([ir.Constant(ir.IntType(32), 1)]))
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _store_fence(typingctx):
    """Order the non-temporal stores before anything after (they bypass the usual store ordering)."""
    sig = types.void()

    def codegen(context, builder, signature, args):
        builder.fence("seq_cst")
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True)
def stream_copy(dst: np.ndarray, start: int, src: np.ndarray) -> None:
    """dst[start:start + len(src)] = src (1-d float64), the aligned middle by non-temporal stores."""
    n = len(src)
    head = min(n, ((-(dst.ctypes.data + 8 * start)) % STREAM_BYTES) // 8)
    for i in range(head):
        dst[start + i] = src[i]
    i = head
    while i + 4 <= n:
        _stream4(dst, start + i, src, i)
        i += 4
    for r in range(i, n):
        dst[start + r] = src[r]


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


@njit(cache=True, error_model="numpy")
def _common_step(P, S, d_old, d_new, U, undelayed, V, thr, m) -> None:
    """Every set one step on: S <- Phi S + Gamma u, u = d V (no loop delay) or the motor's voltage U;
    d_new = the sampled guard's sign flip (meaningful past the controller's start).

    Unsigned indices (no negative-index fix-up) and a select written as
    arithmetic (d - 2 d [flip], exact for d = +-1), so the loop vectorises
    without masked stores.
    """
    for q in range(np.uint64(0), np.uint64(m)):
        I, w, dl, dq = S[0, q], S[1, q], S[2, q], d_old[q]
        ud, um = dq * V[q], U[q]
        u = ud if undelayed[q] else um
        In = P[0, q] * I + P[1, q] * w + P[2, q] * dl + P[9, q] * u
        wn = P[3, q] * I + P[4, q] * w + P[5, q] * dl + P[10, q] * u
        dn = P[6, q] * I + P[7, q] * w + P[8, q] * dl + P[11, q] * u
        S[0, q], S[1, q], S[2, q] = In, wn, dn
        d_new[q] = dq - 2.0 * dq * (dq * dn >= thr[q])


@njit(cache=True)
def _step_matrices(A, B, lengths) -> np.ndarray:
    """(Phi, Gamma) of every set for every distinct length, laid out (length, entry, set) for the lanes."""
    m = A.shape[0]
    P = np.empty((len(lengths), 12, m))
    sets = np.arange(m)
    for j in range(len(lengths)):
        phi_gamma_lanes(A, B, sets, np.full(m, lengths[j]), P[j])
    return P


@njit(cache=True)
def _new_split_gamma(q, key, A, B, keys, gammas, n_split, G) -> int:
    """Gamma(key) computed into set q's cache of split lengths (as ``kernels._delayed``); its slot.

    Only for a length the cache lacks (rare: ``_split_candidates`` fills it
    first).  The look-up itself is written out in ``_schedule``: a call that
    passes arrays updates a reference count per array, which cost ~20 ns per
    delivered command here (2.8 -> 2.4 ms for 1000 delayed sets).
    """
    c = n_split[q]
    if c == MAX_SPLITS:
        c = n_split[q] = 0
    phi_gamma_into(A[q], B[q], key, G)
    keys[q, c] = key
    gammas[q, c, 0], gammas[q, c, 1], gammas[q, c, 2] = G[9], G[10], G[11]
    n_split[q] += 1
    return c


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

    A head start only: ``_schedule`` finds them there, and computes any it
    misses (a key rounded the other way, a full cache) -- the values are the
    same either way.
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


@njit(cache=True)
def _arrivals(j, events, head, nxt, S, U, moved) -> int:
    """Apply the commands reaching their motors inside step j: the motor takes its new voltage and, where it
    changed, the state gets ``kernels._delayed``'s correction (worked out when the command was filed, see
    ``_schedule``) added to the common part in S; returns how many sets moved (``moved[:n]``)."""
    n_moved = 0
    e = head[j]
    while e >= 0:
        q = int(events[e, 0])
        U[q] = events[e, 4]
        if events[e, 5] != 0.0:
            S[0, q], S[1, q], S[2, q] = S[0, q] + events[e, 1], S[1, q] + events[e, 2], S[2, q] + events[e, 3]
            moved[n_moved] = q
            n_moved += 1
        e = nxt[e]
    return n_moved


@njit(cache=True)
def run_linear_lanes(t, A, B, R, guard, V, Td, x0, log, closed_loop, start, first, dir0, Y, dirs) -> None:
    """The automaton for m sets side by side: fills Y = (current, omega, delta) (n, 3, m) and dirs (n, m).

    A (m, 3, 3), B (m, 3); R, guard, V, Td (m,); the other arguments as
    ``kernels.run_linear_batch``.  theta = delta / R is left to the caller.
    A command of a delayed set decided at t_k reaches its motor at t_k + Td:
    it is filed under the step it lands in (``head``/``nxt``: one list per
    step) with its effect (``_schedule``) and applied there (``_arrivals``).
    """
    n, m = len(t), len(R)
    lengths, idx = step_lengths(t)
    P = _step_matrices(A, B, lengths)
    thr = np.empty(m)
    undelayed = np.empty(m, dtype=np.bool_)
    for q in range(m):
        thr[q] = guard_threshold(R[q], guard[q])
        undelayed[q] = closed_loop and Td[q] == 0.0
    delayed = not undelayed.all()
    delayed_set = ~undelayed
    flags = np.zeros(8 * ((m + 7) // 8), dtype=np.uint8)     # whole words for ``_schedule``
    S = np.empty((3, m))
    d_old, d_new = np.zeros(m), np.empty(m)
    U = np.zeros(m)                                   # motor voltage of delayed sets: off until a command arrives
    # commands on their way, one record per set and step of arrival: set, correction (3), volts, changed
    events = np.empty((4 * m if delayed else 0, 6))          # grown as needed
    head = np.full(n, -1)
    nxt = np.empty(len(events), dtype=np.int64)
    n_events = 0
    keys, gammas, n_split = np.empty((m, MAX_SPLITS)), np.empty((m, MAX_SPLITS, 3)), np.zeros(m, dtype=np.int64)
    splits = (keys, gammas, n_split, np.empty(12))
    last = (np.zeros(m), np.full(m, -1), np.zeros(m, dtype=np.int64))
    moved = np.empty(m, dtype=np.int64)
    if delayed:
        _split_candidates(t, A, B, Td, undelayed, keys, gammas, n_split)
    Yf = Y.reshape(Y.size)
    Sf = S.reshape(3 * m)
    for q in range(m):
        S[0, q], S[1, q], S[2, q] = x0[0], x0[1], x0[2]
        d_new[q] = decide(0, 0, x0[2] / R[q], guard[q], log, closed_loop, start, first, dir0)
    for k in range(n):
        if k > 0:
            j = idx[k - 1]
            _common_step(P[j], S, d_old, d_new, U, undelayed, V, thr, m)
            if delayed:
                n_moved = _arrivals(k - 1, events, head, nxt, S, U, moved)
                if closed_loop and k > start:           # re-decide where a correction moved the state
                    for i in range(n_moved):
                        q = moved[i]
                        dq = d_old[q]
                        d_new[q] = dq - 2.0 * dq * (dq * S[2, q] >= thr[q])
            if not closed_loop or k < start:
                for q in range(m):
                    d_new[q] = log[k]
            elif k == start:
                for q in range(m):
                    d_new[q] = decide(k, int(d_old[q]), S[2, q] / R[q], guard[q], log, closed_loop, start,
                                      first, dir0)
        if delayed:
            if len(events) - n_events < m:             # room for every set changing at once
                events, nxt = _grown(events, nxt, n_events + m)
            n_changed = _flag_changes(d_old, d_new, delayed_set, flags, m)
            if n_changed:
                n_events = _schedule(k, t, Td, V, d_new, flags, P, idx, A, B, splits, last, events, nxt, head,
                                     n_events)
        stream_copy(Yf, k * 3 * m, Sf)
        for q in range(m):
            dirs[k, q] = np.int8(d_new[q])
        d_old, d_new = d_new, d_old
    _store_fence()


@njit(cache=True)
def _schedule(k, t, Td, V, d_new, flags, Pj_of, idx, A, B, splits, last, events, nxt, head, n_events) -> int:
    """File the commands of the sets flagged at sample k (``_flag_changes``) under the step s they reach the
    motor in (``arrive < t_s+1 - TIME_EPS``, as ``kernels._delayed`` applies its queue), with what they do there.

    A set's commands arrive in the order they were decided, so the voltage a
    command replaces is the one filed before it (``last``: volts, step and
    event of each set's latest command): du and the correction
    sum of Gamma(h - a) du are known now, in ``kernels._delayed``'s order (a
    second command landing in the same step adds to the first's record).
    Returns the event count.
    """
    n = len(t)
    keys, gammas, n_split, G = splits
    last_volts, last_step, last_event = last
    words = flags.view(np.uint64)                       # eight sets at a time: most are unflagged
    for wi in range(len(words)):
        if words[wi] == 0:
            continue
        for q in range(8 * wi, 8 * wi + 8):
            if not flags[q]:
                continue
            arrive = t[k] + Td[q]
            s = k
            while s < n - 1 and not arrive < t[s + 1] - TIME_EPS:
                s += 1
            if s == n - 1:                              # arrives after the last sample
                continue
            volts = d_new[q] * V[q]
            du = volts - last_volts[q]
            last_volts[q] = volts
            e0 = e1 = e2 = 0.0
            if du != 0.0:
                a = arrive - t[s]
                if a <= TIME_EPS:
                    Pj = Pj_of[idx[s]]
                    e0, e1, e2 = Pj[9, q] * du, Pj[10, q] * du, Pj[11, q] * du
                else:
                    key = step_key((t[s + 1] - t[s]) - a)
                    c = 0
                    while c < n_split[q] and keys[q, c] != key:     # Gamma(key) in the set's cache
                        c += 1
                    if c == n_split[q]:
                        c = _new_split_gamma(q, key, A, B, keys, gammas, n_split, G)
                    e0, e1, e2 = gammas[q, c, 0] * du, gammas[q, c, 1] * du, gammas[q, c, 2] * du
            if last_step[q] == s:                       # a second arrival in the same step: one record
                r = last_event[q]
                if du != 0.0:
                    events[r, 1], events[r, 2], events[r, 3] = events[r, 1] + e0, events[r, 2] + e1, events[r, 3] + e2
                    events[r, 5] = 1.0
                events[r, 4] = volts
                continue
            events[n_events, 0] = q
            events[n_events, 1], events[n_events, 2], events[n_events, 3] = 0.0 + e0, 0.0 + e1, 0.0 + e2
            events[n_events, 4], events[n_events, 5] = volts, 1.0 if du != 0.0 else 0.0
            nxt[n_events] = head[s]                     # the step's list, newest first: order within a step
            head[s] = n_events                          # does not matter (one record per set)
            last_step[q], last_event[q] = s, n_events
            n_events += 1
    return n_events


@njit(cache=True, error_model="numpy")
def _flag_changes(d_old, d_new, delayed_set, flags, m) -> int:
    """flags[q] = 1 where a delayed set's command changed; returns how many (vectorised: most samples
    change none, or a few of many sets)."""
    changes = 0
    for q in range(np.uint64(0), np.uint64(m)):
        f = np.uint8((d_new[q] != d_old[q]) & delayed_set[q])
        flags[q] = f
        changes += f
    return changes


@njit(cache=True)
def _grown(events, nxt, need):
    """Room for ``need`` records: the records and links copied into larger arrays (plain loops: numba's
    slice assignment of 2-d arrays costs ~9 s of JIT compile)."""
    more = np.empty((max(2 * len(events), need), events.shape[1]))
    more_nxt = np.empty(len(more), dtype=np.int64)
    for e in range(len(events)):
        for c in range(events.shape[1]):
            more[e, c] = events[e, c]
        more_nxt[e] = nxt[e]
    return more, more_nxt


def lane_outputs(m: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Outputs for ``run_linear_lanes``: current, omega, delta as one (n, 3, m) block whose start is aligned for
    ``stream_copy`` (numpy backs a block this size with huge pages), dirs (n, m) int8."""
    size = 3 * m * n
    pad = STREAM_BYTES // 8
    buf = np.empty(size + pad)
    off = (-buf.ctypes.data % STREAM_BYTES) // 8
    return buf[off:off + size].reshape(n, 3, m), np.empty((n, m), dtype=np.int8)
