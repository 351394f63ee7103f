"""The agents' per-tick rules that became one compiled pass each, timed against the numpy rules
they replaced, on the same inputs: ``python -m bench.tick_rules [--sizes 25,100]``.

For each size, ``swarm simulate`` flies the bench's N-drone hover grid (bench/side_by_side.py's,
in this process, no report kept) and the inputs of each rule's call at round 1000 (t = 20 s, the
swarm hovering) are kept: the take-off clock (``BatchTakeoff.update``), the neighbour query
(``NeighbourTable.query``) and the readiness (``BatchReadiness.update``). Each is then called
on copies of those inputs, the compiled rule and its numpy reference (the tests' references,
which check that both give the same bits: tests/test_flight_phase.py, tests/test_neighbours.py),
best of 7 repeats of 300 calls each; per call in us. Per-call timing in one process is what a
shared machine whose speed swings by a fifth from run to run can still compare; a whole
flight's difference of a few per cent it cannot. Writes ``bench/results_tick_rules.json``.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import sys
import tempfile
import timeit
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.provenance import ROOT, write_result

OUT = ROOT / "bench" / "results_tick_rules.json"
#: the round whose inputs are kept (t = 20 s at 50 Hz)
ROUND = 1000


def _best_us(call: Callable[[], Any], number: int = 300, repeat: int = 7) -> float:
    return round(min(timeit.repeat(call, number=number, repeat=repeat)) / number * 1e6, 1)


def _captured(n: int) -> dict[str, tuple[Any, tuple[Any, ...]]]:
    """Each rule's object and arguments at :data:`ROUND` of the N-drone grid's flight."""
    from bench.side_by_side import SPACING_M
    from drone_agent.core import flight_phase, neighbours
    from gcs.reference.simulate import simulate
    from protocols.scenario.generator import GeneratorOptions, generate
    from protocols.scenario.scenario_file import load_scenario

    kept: dict[str, tuple[Any, tuple[Any, ...]]] = {}
    rules = {
        "query": (neighbours.NeighbourTable, "query"),
        "readiness": (flight_phase.BatchReadiness, "update"),
        "takeoff": (flight_phase.BatchTakeoff, "update"),
    }
    originals = {name: getattr(cls, method) for name, (cls, method) in rules.items()}

    def keeping(name: str) -> Callable[..., Any]:
        rule = originals[name]

        def call(self: Any, *args: Any) -> Any:
            if name not in kept and len(args) > 1 and args[1] == ROUND:
                kept[name] = (copy.deepcopy(self), copy.deepcopy(args))
            return rule(self, *args)

        return call

    for name, (cls, method) in rules.items():
        setattr(cls, method, keeping(name))
    try:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / f"hover{n}.toml"
            options = GeneratorOptions(n, "grid", spacing_m=SPACING_M, template="hover")
            path.write_text(generate(options, str(path)).text)
            scenario = dataclasses.replace(load_scenario(path), duration_s=(ROUND + 50) * 0.02)
            simulate(scenario, Path(tmp) / "report", plots=False, recording=False)
    finally:
        for name, (cls, method) in rules.items():
            setattr(cls, method, originals[name])
    return kept


def measure(n: int) -> dict[str, Any]:
    """The three rules at N drones: per-call us, numpy and compiled."""
    sys.path.insert(0, str(ROOT / "tests"))  # the numpy references live beside their tests
    from test_flight_phase import _NumpyReadiness, _takeoff_rule
    from test_neighbours import _query_rule

    kept = _captured(n)
    table, (agents, round_now) = kept["query"]
    rows = np.asarray(table.rows_of(agents), dtype=np.intp)
    readiness, args = kept["readiness"]
    reference = _NumpyReadiness.__new__(_NumpyReadiness)
    reference.__dict__.update(copy.deepcopy(readiness.__dict__))
    clock, (t_rows, t_round, committed, arrivals) = kept["takeoff"]
    state = (clock.advertised.copy(), clock._heard.copy(), clock._heard_at.copy())

    def takeoff_numpy() -> Any:
        receiver, takeoff = arrivals.receiver, arrivals.takeoff
        return _takeoff_rule(state, list(t_rows), t_round, list(committed), receiver, takeoff,
                             clock.timeout)  # fmt: skip

    rules = {
        "takeoff_clock": (
            takeoff_numpy,
            lambda: clock.update(t_rows, t_round, committed, arrivals),
        ),
        "neighbour_query": (
            lambda: _query_rule(table, rows, round_now),
            lambda: table.query(agents, round_now),
        ),
        "readiness": (lambda: reference.update(*args), lambda: readiness.update(*args)),
    }
    row: dict[str, Any] = {"n": n, "round": ROUND, "arrivals": int(arrivals.receiver.shape[0])}
    for name, (numpy_rule, compiled_rule) in rules.items():
        row[name] = {"numpy_us": _best_us(numpy_rule), "compiled_us": _best_us(compiled_rule)}
    row["all_three"] = {
        key: round(sum(row[name][key] for name in rules), 1) for key in ("numpy_us", "compiled_us")
    }
    return row


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.tick_rules", description=__doc__)
    parser.add_argument("--sizes", default="25,100", help="drone counts, comma separated")
    args = parser.parse_args(argv)
    try:
        sizes = [int(x) for x in args.sizes.split(",")]
    except ValueError:
        parser.error(f"--sizes: expected numbers like 25,100, got {args.sizes!r}")
    rows = [measure(n) for n in sizes]
    write_result(OUT, {"command": "python -m bench.tick_rules", "rows": rows})
    for row in rows:
        print(f"N = {row['n']}: " + "; ".join(
            f"{name} {row[name]['numpy_us']} -> {row[name]['compiled_us']} us"
            for name in ("takeoff_clock", "neighbour_query", "readiness", "all_three")
        ))  # fmt: skip
    print(f"wrote {OUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
