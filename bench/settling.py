"""How long the consensus estimates take to agree, against swarm size and radio range.

``python -m bench.settling [--sizes 9,25,49,100,250] [--ranges 6,10] [--out FILE]`` (in ``make
bench`` as ``settling``, which writes ``bench/results_settling.json``; a few minutes).

Drones stand on the ground in a square grid (2.5 m apart, the large-swarm scenarios' layout) and
run the real estimator (all of them as the rows of one
:class:`~drone_agent.core.consensus.estimator.BatchConsensus`, each row exactly one
:class:`~drone_agent.core.consensus.scalar.ConsensusEstimator`: tests/test_batch_core.py) with the
one-tick message delay of the in-process radio. Measured, in simulated seconds from power-on:

- ``settle_s``: every agent's estimate of the swarm centre and covariance is within 2 % of the
  truth (centre error and largest covariance-entry error, each divided by the swarm's size
  ``trace(Sigma)`` resp. its square root), and stays there;
- ``agree_s``: the agents' own settling rule (drone_agent.core.flight_phase.Settling: neighbour
  disagreement below 2 % for 25 ticks) holds for every agent;
- ``resettle_s``: after one interior agent drops out at ``settle`` + 2 s, how long until every
  remaining estimate is within 2 % of the new truth again.

The estimator's linearisation ``gamma_dot = -f rho c L gamma`` converges at ``f rho c lambda_2(L)``
per second, while ``tanh`` caps each edge's rate at ``rho`` per channel unit; both are printed
(``lambda2``, ``lambda_max``; ``step_gain`` with the fixed rho, ``capped_step_gain`` with the
step cap of drone_agent/core/consensus/scalar.py, the one flown) so a slow case can be told from an
unstable one.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from bench.provenance import write_result
from drone_agent.core.consensus.estimator import BatchConsensus
from drone_agent.core.consensus.scalar import ConsensusParams
from drone_agent.core.moments import (
    channels_batch,
    moments_from_averages,
    moments_from_averages_batch,
)
from protocols.model.frames import FloatArray
from protocols.wire.consensus_message import ConsensusMessage

TOLERANCE = 0.02
SETTLE_TICKS = 25


def grid(n: int, spacing_m: float = 2.5) -> FloatArray:
    """``n`` positions (NED, on the ground) filling a square grid row by row."""
    side = math.ceil(math.sqrt(n))
    ij = np.array([(k // side, k % side) for k in range(n)], dtype=float)
    pos = np.zeros((n, 3))
    pos[:, :2] = ij * spacing_m
    return pos


def laplacian_spectrum(adjacency: FloatArray) -> tuple[float, float]:
    """(lambda_2, lambda_max) of the graph Laplacian."""
    lap = np.diag(adjacency.sum(axis=1)) - adjacency
    eig = np.linalg.eigvalsh(lap)
    return float(eig[1]), float(eig[-1])


def _errors(estimates: FloatArray, truth: FloatArray, ref: FloatArray) -> float:
    """Largest relative error over agents of centre and covariance (see module doc)."""
    zero = np.zeros(3)
    true_m = moments_from_averages(truth, ref, zero)
    size = float(np.trace(true_m.sigma_m2))
    k = estimates.shape[0]
    m = moments_from_averages_batch(estimates, np.tile(ref, (k, 1)), np.zeros((k, 3)))
    centre = np.abs(m.centre_ned_m - true_m.centre_ned_m).max() / math.sqrt(size)
    shape = np.abs(m.sigma_m2 - true_m.sigma_m2).max() / size
    return float(max(centre, shape, 0.0))


def settle(
    n: int, range_m: float, params: ConsensusParams, max_s: float = 60.0, drop: bool = True
) -> dict[str, Any]:
    """One measurement (see module doc)."""
    pos = grid(n)
    ref = pos.mean(axis=0) + np.array([1.0, -0.5, 0.0])  # the plan's centre is never exact
    zeta = channels_batch(pos, np.zeros((n, 3)), ref, np.zeros(3))
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    adjacency = ((d < range_m) & (d > 0)).astype(float)
    lam2, lam_max = laplacian_spectrum(adjacency)
    degree = adjacency.sum(axis=1)
    pair_degree = np.maximum(degree[:, None], degree[None, :])
    weights = adjacency * np.minimum(params.rho, params.rho_cap / np.maximum(pair_degree, 1))
    capped_lam_max = laplacian_spectrum(weights)[1]
    core = BatchConsensus(range(n), params)
    agents = set(range(n))
    neighbours = {i: np.flatnonzero(adjacency[i]).tolist() for i in range(n)}
    outbox: dict[int, ConsensusMessage] = {}
    calm = dict.fromkeys(range(n), 0)
    dt = params.dt_s
    settle_s = agree_s = resettle_s = None
    drop_at: int | None = None
    dropped: int | None = None
    members = frozenset(range(n))
    ticks = round(max_s / dt)
    t0 = time.perf_counter()
    for k in range(ticks):
        if drop_at is not None and k == drop_at:
            dropped = int(np.argmin(np.linalg.norm(pos - pos.mean(axis=0), axis=1)))
            agents.discard(dropped)
            members = frozenset(agents)
        live = sorted(agents)
        inboxes = [[outbox[j] for j in neighbours[i] if j in outbox and j in members] for i in live]
        gamma, outs = core.step(live, k, zeta[live], inboxes, [members] * len(live))
        outbox = {i: out.message for i, out in zip(live, outs, strict=True)}
        for i, out in zip(live, outs, strict=True):
            calm[i] = calm[i] + 1 if out.disagreement < TOLERANCE and k > 0 else 0
        estimates = gamma
        truth = zeta[live].mean(axis=0)
        err = _errors(estimates, truth, ref)
        t = k * dt
        if drop_at is None:
            settled_now = err <= TOLERANCE
            settle_s = (t if settle_s is None else settle_s) if settled_now else None
            if agree_s is None and all(calm[i] >= SETTLE_TICKS for i in agents):
                agree_s = t
            if settle_s is not None and agree_s is not None and t >= settle_s + 2.0:
                if not drop:
                    break
                drop_at = k + 1
        else:
            if err <= TOLERANCE:
                if resettle_s is None:
                    resettle_s = t - drop_at * dt
            else:
                resettle_s = None
            if resettle_s is not None and t - drop_at * dt >= resettle_s + 2.0:
                break
    degrees = adjacency.sum(axis=1)
    return {
        "n": n,
        "range_m": range_m,
        "degree_min": int(degrees.min()),
        "degree_max": int(degrees.max()),
        "lambda2": round(lam2, 3),
        "lambda_max": round(lam_max, 2),
        "step_gain": round(params.step_gain(lam_max), 3),
        "capped_step_gain": round(params.f * params.c * params.dt_s * capped_lam_max, 3),
        "degree_normalised": params.degree_normalised,
        "rho": params.rho,
        "settle_s": settle_s,
        "agree_s": agree_s,
        "resettle_s": resettle_s,
        "dropped": dropped,
        "wall_s": round(time.perf_counter() - t0, 1),
    }


SIZES = (9, 25, 49, 100, 250)
RANGES = (6.0, 10.0)
OUT_JSON = Path(__file__).resolve().parent / "results_settling.json"


def settling(sizes: tuple[int, ...] = SIZES, ranges: tuple[float, ...] = RANGES) -> dict[str, Any]:
    """The registered benchmark (``make bench``): the scenario library's consensus (default
    parameters: rho 2, c 1, the step cap and channel scale) on every size and range; also
    written to ``bench/results_settling.json``."""
    params = ConsensusParams()
    rows = []
    for r in ranges:
        for n in sizes:
            row = settle(n, r, params)
            rows.append(row)
            print(json.dumps(row), flush=True)
    result = {"command": "python -m bench.settling --out bench/results_settling.json",
              "rows": rows}  # fmt: skip
    write_result(OUT_JSON, result, indent=1)
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="9,25,49,100,250")
    parser.add_argument("--ranges", default="6,10")
    parser.add_argument("--rho", type=float, default=2.0)
    parser.add_argument("--c", type=float, default=1.0)
    parser.add_argument("--degree-normalised", action="store_true")
    parser.add_argument("--max-step-gain", type=float, default=1.4, help="0: no step cap")
    parser.add_argument("--max-s", type=float, default=60.0)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args(argv)
    params = replace(
        ConsensusParams(),
        rho=args.rho,
        c=args.c,
        degree_normalised=args.degree_normalised,
        max_step_gain=args.max_step_gain,
    )
    rows = []
    for r in (float(x) for x in args.ranges.split(",")):
        for n in (int(x) for x in args.sizes.split(",")):
            row = settle(n, r, params, args.max_s)
            rows.append(row)
            print(json.dumps(row), flush=True)
    if args.out is not None:
        command = "python -m bench.settling " + " ".join(argv if argv is not None else sys.argv[1:])
        write_result(args.out, {"command": command, "rows": rows}, indent=1)


if __name__ == "__main__":
    main()
