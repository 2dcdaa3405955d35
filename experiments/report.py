"""Collect the experiment tables and figures into experiments/results/REPORT.md, and fill the
generated tables of README.md and docs/results.md from the result files.

Command:  make report   (= .venv/bin/python experiments/report.py [--quick])
Running time: a second (it only reads what the experiment scripts and `stereojax evaluate` /
`make bench` wrote). Prints the paths it wrote; a table whose script has not been run yet is
listed as missing, with the command that makes it.

A generated table sits between ``<!-- NAME -->`` and ``<!-- /NAME -->`` in a markdown file;
everything between the two markers is replaced, nothing else is touched.
"""

import argparse
import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "experiments" / "results"
SECTIONS = [
    ("table1", "make table1"),
    ("table2", "make sweep-delta"),
    ("table3", "make table3"),
    ("table4", "make table4"),
    ("figures", "make figures"),
    ("depth_example", "make depth-example"),
]
#: the paper's tables that docs/results.md shows, each from experiments/results/<name>.md
DOC_TABLES = ["table1", "table2", "table3", "table4", "cascade_curve", "middlebury_folds_cascade"]
#: the README's results table: (evaluate folder, label, bench chain); numbers from the files
README_ROWS = [
    ("evaluate_kitti2015_best", "**`best` = `kitti2015`** (paper's network, 8 head evaluations per pixel)",
     "kitti2015"),
    ("evaluate_kitti2015_compact", "`kitti2015_compact` (16 maps, head 64-32, 16 evaluations per pixel)",
     "kitti2015_compact"),
    ("evaluate_kitti2015_census", "census + CBCA + SGM + refinement (`--method census`)", "census"),
]
INTRO = """# stereojax — reproduction report

Every number below was produced by the scripts in `experiments/` from the data in
`../shared/data`, on this project's 2-core CPU machine (no GPU); each section ends with the
command that made it. The data we have is much smaller than the paper's (20 KITTI 2015 training
frames instead of 200, one KITTI 2012 frame, seven Middlebury scenes), and the networks in
Tables 1-4 are trained with a reduced *experiment schedule* (1 000 SGD steps of 150 + 150 + 150
patches each, see `experiments/common.py`) and scored in pruned mode (the dense head on the 8
best census candidates of each pixel) so that several seeds fit in one session: compare rows
with each other, and read the spread over seeds before reading a difference. The robustness
tests are reported separately in [robustness.md](robustness.md).
"""


def fill(text: str, blocks: dict) -> str:
    """``text`` with the content between ``<!-- name -->`` and ``<!-- /name -->`` replaced by
    ``blocks[name]`` for every name found (a marker without a block is left as it is)."""
    for name, content in blocks.items():
        pattern = re.compile(rf"(<!-- {re.escape(name)} -->\n)(?:.*?\n)?(<!-- /{re.escape(name)} -->)", re.S)
        text = pattern.sub(lambda m: m.group(1) + content.strip() + "\n" + m.group(2), text)
    return text


def doc_table(md: str) -> str:
    """An experiment's markdown as a part of docs/results.md: its title two levels down and its
    figure links relative to docs/."""
    md = re.sub(r"^# ", "#### ", md.strip(), count=1)
    return re.sub(r"\]\((figures/[^)]+)\)", r"](../experiments/results/\1)", md)


def readme_table(results: Path) -> str | None:
    """The README's KITTI 2015 validation table from the ``stereojax evaluate`` runs and
    ``make bench`` (None while a file is missing)."""
    bench_file = results / "bench.json"
    runs = [(results / folder / "results.json", label, chain) for folder, label, chain in README_ROWS]
    if not bench_file.is_file() or not all(p.is_file() for p, _, _ in runs):
        return None
    bench = json.loads(bench_file.read_text())
    sgbm_s = bench["sgbm_padded_s"]
    lines = ["| method | > 2 px % | > 3 px % | D1 % | EPE px | s / frame | × SGBM (`make bench`) |",
             "|---|---|---|---|---|---|---|"]
    sgbm_seconds = []
    for i, (path, label, chain) in enumerate(runs):
        data = json.loads(path.read_text())
        m = data["mean"]["pipeline"]
        cells = [f"{m[k]:.2f}" for k in ("bad2", "bad3", "d1", "epe")]
        if i == 0:
            cells = [f"**{c}**" for c in cells]
        ratio = bench["chains"][chain]["warm_s"] / sgbm_s
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {m['seconds_warm']:.1f} | {ratio:.0f}× |")
        if "sgbm" in data["mean"]:
            sgbm = data["mean"]["sgbm"]
            sgbm_seconds.append(sgbm["seconds_warm"])
    lo, hi = min(sgbm_seconds), max(sgbm_seconds)
    lines.append("| OpenCV StereoSGBM (3-way, left-padded) | " + " | ".join(
        f"{sgbm[k]:.2f}" for k in ("bad2", "bad3", "d1", "epe")) + f" | {lo:.2f}–{hi:.2f} | 1× |")
    return "\n".join(lines)


#: the README's all-pixel table: (evaluate folder, row label); numbers from the files
#: the Middlebury fold run of the neutral strip (`make middlebury-folds`)

ALL_PIXEL_ROWS = [
    ("evaluate_kitti2015_000001_both", "KITTI 2015 000001 (the one frame with `disp_occ`; a training frame)"),
    ("evaluate_kitti2012_best", "KITTI 2012 000000 (never trained on)"),
    ("evaluate_middlebury_best", "Middlebury, 5 scenes with a non-occlusion mask (4 trained on, Motorcycle not)"),
]


def all_pixel_table(results: Path) -> str | None:
    """The README's table of `best` against SGBM on all ground-truth pixels (None while a file
    is missing)."""
    paths = [(results / folder / "results.json", label) for folder, label in ALL_PIXEL_ROWS]
    if not all(p.is_file() for p, _ in paths):
        return None
    lines = ["| frames | `best` > 3 px % | SGBM > 3 px % | `best` D1 % | SGBM D1 % | `best` non-occluded > 3 px % |",
             "|---|---|---|---|---|---|"]
    for path, label in paths:
        mean = json.loads(path.read_text())["mean"]
        best = mean.get("pipeline (all)", mean.get("pipeline"))
        sgbm = mean.get("sgbm (all)", mean.get("sgbm"))
        noc = mean.get("pipeline (noc)")
        lines.append(f"| {label} | {best['bad3']:.2f} | {sgbm['bad3']:.2f} | {best['d1']:.2f} | {sgbm['d1']:.2f} | "
                     + (f"{noc['bad3']:.2f}" if noc else "n/a") + " |")
    indoor = results / "indoor_folds.json"
    if indoor.is_file():    # each scene scored by a fold model that never saw its family (no D1 here)
        mean = json.loads(indoor.read_text())["mean"]
        lines.append(f"| Middlebury, 24 scenes in 3 folds by family (each scored by a model fine-tuned without its "
                     f"family; the shipped model's recipe) | {mean['fold']:.2f} | {mean['sgbm']:.2f} | n/a | n/a | n/a |")
    return "\n".join(lines)


def speed_table(results: Path) -> str | None:
    """The README's speed table from ``make bench`` (None without bench.json)."""
    bench_file = results / "bench.json"
    if not bench_file.is_file():
        return None
    bench = json.loads(bench_file.read_text())
    sgbm_s = bench["sgbm_padded_s"]
    lines = ["| method | warm s / frame | × SGBM |", "|---|---|---|", f"| OpenCV StereoSGBM | {sgbm_s:.3f} | 1× |"]
    xla = bench.get("chains_xla") or {}     # the JAX kernels beside the native ones (issue 51)
    for chain, label in (("census", "census chain"), ("kitti2015_compact", "`kitti2015_compact`"),
                         ("kitti2015", "`best` = `kitti2015`")):
        s = bench["chains"][chain]["warm_s"]
        lines.append(f"| {label} | {s:.2f} | {s / sgbm_s:.0f}× |")
        if "warm_s" in xla.get(chain, {}):
            s = xla[chain]["warm_s"]
            lines.append(f"| {label}, JAX kernels (`--kernels xla`) | {s:.2f} | {s / sgbm_s:.0f}× |")
    casc = bench["chains"].get("cascade", {})
    if "warm_s" in casc:
        s = casc["warm_s"]
        lines.append(f"| cascade, `kitti2015` at {100 * casc['share']:g} % of the pixels (not `best`) | {s:.2f} | "
                     f"{s / sgbm_s:.0f}× |")
    return "\n".join(lines)


def write_text(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


def fill_file(path: Path, blocks: dict) -> bool:
    """Fill the generated tables of one markdown file; whether it changed."""
    if not path.is_file():
        return False
    old = path.read_text()
    new = fill(old, {k: v for k, v in blocks.items() if v is not None})
    if new != old:
        write_text(path, new)
    return new != old


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="collect the --quick outputs instead (the README "
                    "and docs are then left as they are)")
    ap.add_argument("--results", default=str(RESULTS))
    ap.add_argument("--root", default=str(ROOT), help="the project folder whose README.md and docs/ are filled")
    args = ap.parse_args()
    results = Path(args.results)
    parts, missing = [INTRO], []
    for stem, command in SECTIONS:
        md = results / (f"{stem}_quick.md" if args.quick else f"{stem}.md")
        if md.is_file():
            text = md.read_text().strip()
            parts.append("#" + text if text.startswith("# ") else text)   # demote to a section
        else:
            missing.append(stem)
            parts.append(f"## {stem}\n\nNot run yet: `{command}`.")
    out = results / ("REPORT_quick.md" if args.quick else "REPORT.md")
    write_text(out, "\n\n".join(parts) + "\n")
    print(f"-> {out}" + (f" (missing: {', '.join(missing)})" if missing else ""))
    if args.quick:
        return
    root = Path(args.root)
    docs = {name: doc_table((results / f"{name}.md").read_text()) for name in DOC_TABLES
            if (results / f"{name}.md").is_file()}
    readme = {"results_table": readme_table(results), "speed_table": speed_table(results),
              "all_pixel_table": all_pixel_table(results)}
    for path, blocks in ((root / "docs" / "results.md", docs), (root / "README.md", readme)):
        print(f"-> {path}" + (" (tables filled)" if fill_file(path, blocks) else " (tables up to date)"))


if __name__ == "__main__":
    main()
