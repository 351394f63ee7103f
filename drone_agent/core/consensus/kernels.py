"""The compiled loops of the consensus step (drone_agent/core/consensus/estimator.py): the pairing
rules and the increments over a step's due values, and each row's edge sums
(drone_agent/core/jit_math.py: numba, compiled on first use). Pure and I/O-free."""

from __future__ import annotations

import numpy as np

from drone_agent.core.jit_math import jit, nmax, nmin


@jit
def pair_rounds(  # type: ignore[no-untyped-def]
    rows,
    pos,
    sender,
    rounds,
    msg,
    ids,
    round_,
    hist_round,
    hist_heard,
    hist_gamma,
    hist_degree,
    hist_largest,
    edge,
    edge_round,
    heard_by,
    gamma_msg,
    degree_msg,
    gains,
    scales,
    disagreement,
    integrated,
    heads,
    steps,
    args,
):
    """:meth:`~drone_agent.core.consensus.estimator.BatchConsensus._integrate` over the due values
    (T,), ordered by (agent, neighbour, round): which pass rules 2, 3 and 6 (``integrated``),
    the disagreement per position (the largest scaled difference), ``heads`` (the first
    integrated value of each (agent, neighbour)), and for the integrated ones, in order, the
    gain ``rho dt`` (``steps``) and the tanh arguments ``c diff / scale`` per channel (``args``,
    rows 0..n). Returns n."""
    rho0, rho_cap, dt, c, normalised = gains
    h = hist_round.shape[1]
    n_ok = 0
    last_pos, last_j = -1, -1
    for t in range(pos.shape[0]):
        p, j, q, u = pos[t], sender[t], rounds[t], msg[t]
        r = rows[p]
        slot = q % h
        if not (
            hist_round[r, slot] == q
            and hist_heard[r, slot, j]
            and (not edge[r, j] or q > edge_round[r, j])
            and heard_by[u, ids[r]]
        ):
            continue
        integrated[t] = True
        pair_degree = max(max(hist_degree[r, slot], degree_msg[u]), 1)
        rho = rho0
        if normalised:
            rho = rho / pair_degree
        rho = nmin(rho, rho_cap / pair_degree)  # the step cap (consensus.py)
        rho = rho / max(round_ - q, 1)  # delay-scaled gain (module doc)
        largest_j, worst = 0.0, 0.0
        for ch in range(scales.shape[0]):  # per channel scale (consensus.py)
            diff = hist_gamma[r, slot, ch] - gamma_msg[u, ch]
            largest_j = nmax(largest_j, abs(gamma_msg[u, ch]))
            worst = nmax(worst, abs(diff))
            args[n_ok, ch] = c * diff / scales[ch]
        # max |gamma| per own round (kept with the history) and per message
        scaled = worst / (1.0 + nmax(hist_largest[r, slot], largest_j))
        first_of_row = p != last_pos
        disagreement[p] = scaled if first_of_row else nmax(disagreement[p], scaled)
        steps[n_ok] = rho * dt
        heads[t] = first_of_row or j != last_j
        last_pos, last_j = p, j
        n_ok += 1
    return n_ok


@jit
def pair_increments(  # type: ignore[no-untyped-def]
    rows, pos, sender, rounds, integrated, steps, tanh_args, scales, q_own, edge, edge_round
):
    """Each integrated value's increment ``rho dt scale tanh(...)`` subtracted from ``q_own`` in
    order (several rounds on one edge add up in round order, as one agent integrating them one
    after the other), the edge marked with its newest integrated round."""
    k = 0
    for t in range(pos.shape[0]):
        if not integrated[t]:
            continue
        r, j, q = rows[pos[t]], sender[t], rounds[t]
        for ch in range(scales.shape[0]):
            q_own[r, j, ch] = q_own[r, j, ch] - steps[k] * scales[ch] * tanh_args[k, ch]
        edge_round[r, j] = max(edge_round[r, j], q) if edge[r, j] else q
        edge[r, j] = True
        k += 1


@jit
def edge_sums(rows, edge, has_q_for_me, q_for_me, q_own, q_recv, total):  # type: ignore[no-untyped-def]
    """``sum_j (Q_ij - Q_ji)`` (P, 18) into ``total`` over each row's edges, in neighbour order,
    ``Q_ji`` refreshed from the newest message of j that carried one (rule 1); a row with no edge
    keeps its ``total``."""
    for p in range(rows.shape[0]):
        r = rows[p]
        started = False
        for j in range(edge.shape[1]):
            if not edge[r, j]:
                continue
            fresh = has_q_for_me[r, j]  # rule 1: the newest Q_ji heard
            for ch in range(total.shape[1]):
                if fresh:
                    q_recv[r, j, ch] = q_for_me[r, j, ch]
                d = q_own[r, j, ch] - q_recv[r, j, ch]
                total[p, ch] = total[p, ch] + d if started else d
            started = True


@jit
def receive_common(  # type: ignore[no-untyped-def]
    rows,
    pos,
    sender,
    rounds,
    which,
    incarnation,
    at,
    keys,
    span,
    sums,
    tags,
    ids,
    own_inc,
    inc,
    member_mask,
    round_,
    history,
    peer,
    arrived,
    latest,
    has_q_for_me,
    q_for_me,
):
    """:meth:`~drone_agent.core.consensus.estimator.BatchConsensus._receive` of a step whose
    values are all of the usual kind, in one pass: every value valid (not the row's own, within
    the history, listed by the row's membership view: ``member_mask`` (P, M), or (0, 0) for no
    view), of the incarnation known of its sender, due (a round before ``round_``), no two alike
    and in (agent, sender, round) order, and every message read from one step's arrays (``at``
    its position in them: ``keys``, ``span``, ``sums``, ``tags`` of its
    :class:`~drone_agent.core.consensus.packing.Pack`). Checks all that first and returns False,
    changing nothing, if any value is not so (the caller files them the general way); else
    notes every value's sender heard this round and each (agent, sender)'s newest round and the
    ``Q_ji`` it carries (made with the agent's own incarnation), as the general way does, and
    returns True: every value is due, in the order given."""
    n = pos.shape[0]
    masked = member_mask.shape[0] > 0
    oldest = round_ - history
    for t in range(n):
        p, j, q = pos[t], sender[t], rounds[t]
        r = rows[p]
        me = ids[r]
        if j == me or j < 0 or q < oldest or q >= round_ or me >= span:
            return False
        if masked and not member_mask[p, j]:
            return False
        if incarnation[which[t]] != inc[r, j]:
            return False
        if t > 0:
            p0, j0 = pos[t - 1], sender[t - 1]
            if p < p0 or (p == p0 and (j < j0 or (j == j0 and q <= rounds[t - 1]))):
                return False
    n_keys = keys.shape[0]
    for t in range(n):
        p, j, q = pos[t], sender[t], rounds[t]
        r = rows[p]
        peer[r, j] = True
        arrived[r, j] = round_
        if t + 1 < n and pos[t + 1] == p and sender[t + 1] == j:
            continue  # not the newest of its (agent, sender): the last one is
        if q <= latest[r, j]:
            continue
        latest[r, j] = q
        wanted = at[which[t]] * span + ids[r]
        lo, hi = 0, n_keys  # the first key >= wanted
        while lo < hi:
            mid = (lo + hi) // 2
            if keys[mid] < wanted:
                lo = mid + 1
            else:
                hi = mid
        has = lo < n_keys and keys[lo] == wanted
        if has:
            tag = tags[lo]
            has = tag < 0 or tag == own_inc[r]  # made with this incarnation
        has_q_for_me[r, j] = has
        if has:
            for ch in range(sums.shape[1]):
                q_for_me[r, j, ch] = sums[lo, ch]
    return True


@jit
def any_dead(rows, peer, edge, member_mask):  # type: ignore[no-untyped-def]
    """Whether a row has a peer or an edge its membership view (``member_mask`` (P, M)) no
    longer lists (rule 5 then drops them)."""
    for p in range(rows.shape[0]):
        r = rows[p]
        for j in range(member_mask.shape[1]):
            if (peer[r, j] or edge[r, j]) and not member_mask[p, j]:
                return True
    return False


@jit
def heard_now(rows, peer, arrived, oldest, heard, degree):  # type: ignore[no-untyped-def]
    """Which peers each row hears (``heard`` (P, M)): a message of theirs arrived at round
    ``oldest`` or later; and how many (``degree`` (P,))."""
    for p in range(rows.shape[0]):
        r = rows[p]
        d = 0
        for j in range(heard.shape[1]):
            h = peer[r, j] and arrived[r, j] >= oldest
            heard[p, j] = h
            d += h
        degree[p] = d


@jit
def settle(  # type: ignore[no-untyped-def]
    rows,
    round_,
    half_f,
    zeta,
    edge,
    has_q_for_me,
    q_for_me,
    q_own,
    q_recv,
    heard,
    degree,
    hist_round,
    hist_gamma,
    hist_largest,
    hist_degree,
    hist_heard,
    gamma,
):
    """Each row's estimate ``gamma = f/2 sum_j (Q_ij - Q_ji) + zeta`` (:func:`edge_sums`; ``half_f``
    is ``f * 0.5``), and its round in the history: the round, gamma, its largest magnitude, the
    degree and the heard-set, in slot ``round_ % history``."""
    edge_sums(rows, edge, has_q_for_me, q_for_me, q_own, q_recv, gamma)
    slot = round_ % hist_round.shape[1]
    for p in range(rows.shape[0]):
        r = rows[p]
        hist_round[r, slot] = round_
        largest = 0.0
        for ch in range(gamma.shape[1]):
            g = half_f * gamma[p, ch] + zeta[p, ch]
            gamma[p, ch] = g
            hist_gamma[r, slot, ch] = g
            largest = abs(g) if ch == 0 else nmax(largest, abs(g))
        hist_largest[r, slot] = largest
        hist_degree[r, slot] = degree[p]
        for j in range(heard.shape[1]):
            hist_heard[r, slot, j] = heard[p, j]


@jit
def edge_rows(rows, edge, observing, q_own, inc):  # type: ignore[no-untyped-def]
    """What each row's message carries of its edges, the rows in turn and each one's edges in
    neighbour order (a listening row: none): the neighbour ids (E,), their keys ``position * M +
    neighbour`` (E,), the running sums ``Q_ij`` (E, 18) and the incarnations they were made with
    (E,), and where each row's edges start (P + 1,)."""
    n_rows, m = rows.shape[0], edge.shape[1]
    bounds = np.empty(n_rows + 1, dtype=np.int64)
    total = 0
    for p in range(n_rows):
        bounds[p] = total
        r = rows[p]
        if not observing[r]:
            for j in range(m):
                total += edge[r, j]
    bounds[n_rows] = total
    ids = np.empty(total, dtype=np.int64)
    keys = np.empty(total, dtype=np.int64)
    sums = np.empty((total, q_own.shape[2]))
    tags = np.empty(total, dtype=np.int64)
    e = 0
    for p in range(n_rows):
        r = rows[p]
        if observing[r]:
            continue
        for j in range(m):
            if edge[r, j]:
                ids[e] = j
                keys[e] = p * m + j
                tags[e] = inc[r, j]
                for ch in range(q_own.shape[2]):
                    sums[e, ch] = q_own[r, j, ch]
                e += 1
    return ids, keys, sums, tags, bounds
