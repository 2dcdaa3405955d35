"""experiments/bench_report.py: the `make bench` report's target lines (issue 26) each say met or
by how much they are missed, from the numbers of the run they are given."""

import copy
import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments" / "results"


def _load():
    spec = importlib.util.spec_from_file_location("bench_report", ROOT / "experiments" / "bench_report.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


bench = _load()


def _run():
    """A bench result: the committed bench.json, the accuracy records beside it, a demo timing."""
    r = json.loads((RESULTS / "bench.json").read_text())
    r["accuracy"] = bench.accuracy_records(RESULTS)
    r["demo"] = {"warm_s": 9.7, "compile_s": 12.0, "peak_rss_gib": 1.5, "shape": [500, 741], "max_disp": 64,
                 "model": "learned cost, shipped model middlebury_downsize_relaxed"}
    return r


def _section(md: str) -> list[str]:
    part = md.split("## The targets of issue 26")[1].split("\n## ")[0]
    return [line for line in part.splitlines() if line.startswith("* ")]


def _line(lines, start):
    return next(line for line in lines if line.startswith(start))


def test_accuracy_records_come_from_the_results_files():
    acc = bench.accuracy_records(RESULTS)
    dd = json.loads((RESULTS / "dense_distill.json").read_text())
    fin = json.loads((RESULTS / "dense_distill_final.json").read_text())
    assert acc["kitti2015"]["val"] == dd["full"]["val"]
    assert acc["student"]["val"] == fin["val"] and acc["student"]["limit"] == fin["best_limit"]
    assert "middlebury_student" in acc
    assert bench.accuracy_records(Path("/nonexistent")) == {}


def test_issue26_lines_follow_the_numbers_of_the_run():
    r = _run()
    r["machine"] = "Some CPU (avx, fma)"
    md = bench.format_bench(r)
    assert "Some CPU (avx, fma)" in md.splitlines()[0]          # the numbers are for one machine
    lines = _section(md)
    assert len(lines) == 6
    best = r["best"]
    ratio = r["chains"][best]["warm_s"] / r["sgbm_padded_s"]
    first = _line(lines, f"* `best` (= `{best}`), × SGBM ≤ 30×")
    assert f"{ratio:.2f}×" in first and ("**not met**" in first) == (ratio > 30)
    demo = _line(lines, "* `make demo`")
    assert "**not met**, 4.70 s over" in demo and "4.58 %" in demo
    val = _line(lines, "* validation > 3 px of `best`")
    assert f"{r['accuracy'][best]['val']:.2f} %" in val

    # a run that meets them says so
    fast = copy.deepcopy(r)
    fast["chains"][best]["warm_s"] = 10 * fast["sgbm_padded_s"]
    fast["demo"]["warm_s"] = 4.0
    fast["accuracy"][best]["val"] = 3.9
    fast["processes"]["best"]["cold"]["peak_rss_gib"] = 1.0
    lines = _section(bench.format_bench(fast))
    for start in (f"* `best` (= `{best}`)", "* `make demo`", "* validation", "* peak RSS", "* stretch"):
        assert _line(lines, start).endswith("met."), start
        assert "not met" not in _line(lines, start)


def test_report_without_demo_or_records_leaves_those_lines_out():
    r = _run()
    del r["demo"], r["accuracy"]
    lines = _section(bench.format_bench(r))
    assert not any(line.startswith(("* `make demo`", "* validation", "* stretch")) for line in lines)
    assert "No student record" in lines[0]
