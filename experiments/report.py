"""Collect the experiment tables and figures into experiments/results/REPORT.md.

Command:  make report   (= .venv/bin/python experiments/report.py [--quick])
Running time: a second (it only reads the markdown the experiment scripts wrote).
Prints the path of the report; a table whose script has not been run yet is listed as missing,
with the command that makes it.
"""

import argparse
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
SECTIONS = [
    ("table1", "make table1"),
    ("table2", "make sweep-delta"),
    ("table3", "make table3"),
    ("table4", "make table4"),
    ("figures", "make figures"),
    ("depth_example", "make depth-example"),
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


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="collect the --quick outputs instead")
    ap.add_argument("--results", default=str(RESULTS))
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
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text("\n\n".join(parts) + "\n")
    tmp.replace(out)
    print(f"-> {out}" + (f" (missing: {', '.join(missing)})" if missing else ""))


if __name__ == "__main__":
    main()
