"""Every benchmark result file says where its figures come from: the commit and the load."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

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
    speed = got["machine_speed"]  # how fast the machine ran then: figures of two days compare
    assert speed["python_ms"] > 0 and speed["numpy_us"] > 0
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


def test_the_targets_bench_judges_each_figure_by_its_median_and_says_by_how_much(
    tmp_path: Path, monkeypatch: Any
) -> None:
    """bench.targets: the median of the runs against each bound, more-is-better and
    less-is-better alike; a failed run is a row saying so, not a crash; the table and the JSON
    say met or missed and by what factor; an unknown target name is refused in one line."""
    from bench import targets as bt

    runs = iter([{"rtf_loop": 20.0, "whole_s": 2.5}, {"error": "boom"}, {"rtf_loop": 40.0}])

    def run() -> dict[str, Any]:
        row = next(runs)
        if "error" in row:
            raise RuntimeError("boom")
        return row

    fake = bt.Target(
        "fake", "swarm simulate x", run,
        (bt.Figure("rtf_loop", 30.0, True, "x", "loop"),
         bt.Figure("whole_s", 2.0, False, "s", "whole")),
    )  # fmt: skip
    monkeypatch.setattr(bt, "TARGETS", (fake,))
    out = tmp_path / "t.json"
    assert bt.main(["--repeats", "3", "--out", str(out)]) == 0
    got = json.loads(out.read_text())
    assert got["commit"] and len(got["load_average"]) == 3
    (entry,) = got["targets"]
    assert entry["runs"][1] == {"error": "RuntimeError: boom"}
    loop, whole = entry["figures"]
    assert (loop["median"], loop["met"], loop["margin"]) == (30.0, True, 1.0)
    assert (whole["median"], whole["met"], whole["margin"]) == (2.5, False, 0.8)
    assert entry["commit"] == got["commit"] and entry["repeats"] == 3
    md = bt.table(got)
    assert "| fake | `swarm simulate x` | whole | <= 2s | 2.5s | no (0.80 of the bound) |" in md
    with pytest.raises(SystemExit):
        bt.main(["--only", "nope", "--out", str(out)])
    # --only measures those and keeps the other entries of the file as they were measured
    other = bt.Target("other", "swarm up y", lambda: {"rtf_loop": 50.0},
                      (bt.Figure("rtf_loop", 30.0, True, "x", "loop"),))  # fmt: skip
    monkeypatch.setattr(bt, "TARGETS", (fake, other))
    runs = iter([{"rtf_loop": 99.0}])
    assert bt.main(["--only", "other", "--repeats", "1", "--out", str(out)]) == 0
    both = json.loads(out.read_text())
    assert [t["name"] for t in both["targets"]] == ["fake", "other"]
    assert both["targets"][0] == entry
    assert both["targets"][1]["figures"][0]["median"] == 50.0
    assert both["targets"][1]["repeats"] == 1


def test_the_ab_bench_refuses_a_checkout_without_its_venv(tmp_path: Path, capsys: Any) -> None:
    """bench.ab names the checkout that cannot run and stops (exit 2), with no traceback."""
    from bench import ab

    assert ab.main(["--before", str(tmp_path)]) == 2
    assert "has no .venv" in capsys.readouterr().err


def test_the_ab_bench_refuses_sizes_that_are_not_drone_counts(capsys: Any) -> None:
    from bench import ab

    assert ab.main(["--before", str(ab.ROOT), "--sizes", "many"]) == 2
    assert "--sizes takes drone counts" in capsys.readouterr().err
