"""The tables in README.md and docs/results.md are the ones experiments/report.py generates from
experiments/results/ (no number copied by hand), and the filling touches only the marked blocks."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _report():
    spec = importlib.util.spec_from_file_location("report", ROOT / "experiments" / "report.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_fill_replaces_only_between_the_markers():
    report = _report()
    text = "intro\n<!-- t -->\nold 1\nold 2\n<!-- /t -->\nmiddle\n<!-- u -->\nkeep\n<!-- /u -->\nend\n"
    out = report.fill(text, {"t": "new\n", "absent": "x"})
    assert out == "intro\n<!-- t -->\nnew\n<!-- /t -->\nmiddle\n<!-- u -->\nkeep\n<!-- /u -->\nend\n"
    assert report.fill(out, {"t": "new"}) == out                 # filling twice changes nothing
    assert report.fill("<!-- e -->\n<!-- /e -->\n", {"e": "x"}) == "<!-- e -->\nx\n<!-- /e -->\n"   # an empty block


def test_doc_table_demotes_the_title_and_rebases_figure_links():
    report = _report()
    md = "# Table 2 — x\n\n| a |\n|---|\n\n![sweep](figures/table2_delta.png)\n"
    out = report.doc_table(md)
    assert out.startswith("#### Table 2 — x")
    assert "](../experiments/results/figures/table2_delta.png)" in out


def test_committed_readme_and_docs_tables_are_generated_from_the_results_files():
    report = _report()
    results = ROOT / "experiments" / "results"
    blocks = {"results_table": report.readme_table(results), "speed_table": report.speed_table(results),
              "all_pixel_table": report.all_pixel_table(results)}
    assert all(blocks.values()), "a README table has no results file"
    readme = (ROOT / "README.md").read_text()
    assert all(f"<!-- {name} -->" in readme for name in blocks)
    assert report.fill(readme, blocks) == readme, "README tables differ from experiments/results: run make report"
    docs = (ROOT / "docs" / "results.md").read_text()
    tables = {n: report.doc_table((results / f"{n}.md").read_text()) for n in report.DOC_TABLES}
    assert all(f"<!-- {name} -->" in docs for name in tables)
    assert report.fill(docs, tables) == docs, "docs/results.md tables differ from experiments/results: run make report"


def test_the_figures_the_readme_and_usage_quote_in_their_text_are_the_results_files():
    """The scores and ratios written into sentences (not tables) of README.md and docs/usage.md."""
    import json

    results = ROOT / "experiments" / "results"
    mean = {k: json.loads((results / f"evaluate_kitti2015_{k}" / "results.json").read_text())["mean"]
            for k in ("best", "compact")}
    best, compact = (f"{mean[k]['pipeline']['bad3']:.2f} %" for k in ("best", "compact"))
    sgbm = f"{mean['best']['sgbm']['bad3']:.2f} %"
    bench = json.loads((results / "bench.json").read_text())
    ratio = bench["chains"]["kitti2015_compact"]["warm_s"] / bench["sgbm_padded_s"]
    status = (ROOT / "README.md").read_text().split("## Two commands")[0]
    assert f"({best} > 3 px; OpenCV SGBM {sgbm})" in status
    secs = round(bench["chains"]["kitti2015_compact"]["warm_s"])
    assert f"{compact} in about {secs} s ({ratio:.0f}× SGBM in `make bench`)" in status
    usage = (ROOT / "docs" / "usage.md").read_text()
    assert f"{compact} instead of {best} > 3 px" in usage
    assert "../shared/" not in (ROOT / "README.md").read_text().split("## Links")[1]   # no link out of the repo


def test_speed_table_has_the_jax_kernel_rows_when_the_bench_timed_them(tmp_path):
    """Issue 51: the README's speed table sets the JAX kernels' census and compact chains beside the
    native ones when bench.json has them (``chains_xla``), and is as before without them."""
    import json

    report = _report()
    bench = json.loads((ROOT / "experiments" / "results" / "bench.json").read_text())
    bench.pop("chains_xla", None)
    (tmp_path / "bench.json").write_text(json.dumps(bench))
    before = report.speed_table(tmp_path)
    assert "JAX kernels" not in before
    sg = bench["sgbm_padded_s"]
    bench["chains_xla"] = {"census": {"warm_s": 10 * sg}, "kitti2015_compact": {"warm_s": 40 * sg}}
    (tmp_path / "bench.json").write_text(json.dumps(bench))
    lines = report.speed_table(tmp_path).splitlines()
    i = next(i for i, line in enumerate(lines) if line.startswith("| census chain |"))
    assert lines[i + 1] == f"| census chain, JAX kernels (`--kernels xla`) | {10 * sg:.2f} | 10× |"
    assert f"| `kitti2015_compact`, JAX kernels (`--kernels xla`) | {40 * sg:.2f} | 40× |" in lines
    assert [line for line in lines if "JAX kernels" not in line] == before.splitlines()


def test_usage_explains_the_two_sgbm_rows_where_it_describes_sgbm():
    """Issue 55: "SGBM left-padded / unpadded", the rows of `evaluate --sgbm`'s table, was explained
    nowhere a user looks. The bullet of docs/usage.md that describes --sgbm names both rows as the table
    does and says what the padding is."""
    from stereojax.app.evaluation import LABELS

    usage = (ROOT / "docs" / "usage.md").read_text()
    bullets = [b for b in usage.split("\n* ") if "`--sgbm` scores" in b]
    assert len(bullets) == 1, "docs/usage.md: no bullet says what `--sgbm` scores"
    text = " ".join(bullets[0].split())
    for key in ("sgbm", "sgbm_unpadded"):
        assert f'"{LABELS[key]}"' in text, LABELS[key]              # the row's name, as the table prints it
    assert "to the left of both images" in text and "first column" in text and "crops them off" in text
    assert "no estimate in those first N columns" in text


def test_usage_states_the_point_cloud_axes_where_it_describes_ply():
    """The PLY's axis convention was only in a docstring (issue 55): usage.md says it beside --ply."""
    text = (ROOT / "docs" / "usage.md").read_text()
    at = text.index("a coloured point cloud `points.ply`")
    near = text[at:at + 400]
    assert "x right, y down" in near and "z forward" in near and "metres" in near
