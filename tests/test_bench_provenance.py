"""Every benchmark result file says where its figures come from: the commit and the load."""

from __future__ import annotations

import json
import re
from pathlib import Path

from bench.provenance import write_result

BENCH = Path(__file__).resolve().parents[1] / "bench"


def test_a_result_is_written_with_its_commit_load_and_time(tmp_path: Path) -> None:
    out = tmp_path / "sub" / "results_x.json"
    write_result(out, {"rows": [{"n": 9}], "load_average": [0.1, 0.2, 0.3]})
    got = json.loads(out.read_text())
    assert got["rows"] == [{"n": 9}]
    assert got["load_average"] == [0.1, 0.2, 0.3]  # the result's own, from when it started
    assert re.fullmatch(r"[0-9a-f]{7,}(\+changes)?", got["commit"])
    assert got["written_utc"].startswith("20")
    write_result(out, {"rows": []})
    assert len(json.loads(out.read_text())["load_average"]) == 3  # now's, when it has none


def test_every_benchmark_writes_its_file_through_write_result() -> None:
    """No benchmark writes a JSON result of its own making (it would lack the commit and load);
    bench/run.py's combined file carries them in its ``machine`` entry."""
    own = {"provenance.py", "run.py"}
    writers = [
        path.name
        for path in sorted(BENCH.glob("*.py"))
        if path.name not in own and re.search(r"write_text\(\s*json\.dumps", path.read_text())
    ]
    assert writers == []
