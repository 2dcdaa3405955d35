"""Table 2 — sweep of the relaxed loss's margin Delta: disparity error per Delta, mean ± std over
seeds, with a plot.

Command:  make sweep-delta [DELTAS="0 0.03 0.04 0.05 0.06 0.07" SWEEP_SEEDS=2]
          (= .venv/bin/python experiments/sweep_delta.py --deltas 0 0.03 ... --seeds 2 --kitti-frames 3)
          .venv/bin/python experiments/sweep_delta.py --quick      (smoke test, about a minute)
Running time here (2 cores): about 3 min per new model (1000 steps of training + scoring 3 KITTI
frames); Delta 0 and 0.05 are reused from Table 1: about 25 min for the default 6 Deltas x 2
seeds after Table 1. The table and plot are rewritten after every Delta.
Prints and writes experiments/results/table2.{json,md} and figures/table2_delta.png: for each
Delta the > 3 px and > 2 px errors on KITTI 2015 test frames (non-occluded GT, model trained on
000001-000020) and the patch-level validation error, mean ± std over seeds.
"""

import argparse
import json

from common import Setup, add_common_args, mean_std, md_table, pm, write_outputs


def main():
    ap = add_common_args(argparse.ArgumentParser(description=__doc__.splitlines()[0]))
    ap.add_argument("--deltas", type=float, nargs="+", default=[0.0, 0.03, 0.04, 0.05, 0.06, 0.07])
    ap.add_argument("--seeds", type=int, help="seeds per Delta (default 3; quick 1)")
    args = ap.parse_args()
    setup = Setup.from_args(args)
    seeds = list(range(args.seeds or (1 if setup.quick else 3)))
    results = []
    for delta in args.deltas:
        loss = "bce" if delta == 0 else "relaxed"
        per_seed = []
        for seed in seeds:
            run = setup.train("kitti2015", "downsize", loss, delta, seed)
            sc = setup.score_model(run, "kitti2015")
            summary = json.loads((run / "train_summary.json").read_text())
            per_seed.append({"seed": seed, "bad2": sc["mean"]["bad2"], "bad3": sc["mean"]["bad3"],
                             "epe": sc["mean"]["epe"], "patch_error": 100 * summary["validation"]["error"],
                             "run": run.name})
            print(f"  Delta {delta:g} seed {seed}: > 3 px {sc['mean']['bad3']:.2f} %", flush=True)
        results.append({"delta": delta, "seeds": per_seed})
        _write(setup, seeds, results)      # after every Delta, so a stopped sweep keeps what it measured


def _write(setup, seeds, results) -> None:
    rows = [[f"{r['delta']:g}" + (" (plain BCE)" if r["delta"] == 0 else ""),
             pm([s["bad2"] for s in r["seeds"]]), pm([s["bad3"] for s in r["seeds"]]),
             pm([s["epe"] for s in r["seeds"]]), pm([s["patch_error"] for s in r["seeds"]])] for r in results]
    md = (f"# Table 2 — relaxed-loss margin Delta (downsize head, {setup.steps} steps per model, "
          f"{len(seeds)} seed(s), mean ± std)\n\n"
          + md_table(["Delta", "> 2 px %", "> 3 px %", "EPE px", "patch error %"], rows)
          + "\n\nKITTI 2015: trained on 000001-000020, scored on " + ", ".join(setup.frames("test", "kitti2015"))
          + f" (non-occluded GT), full chain in pruned mode (K = {setup.candidates}); patch error on "
          "3 000 fixed pairs of 000021-000030.\n\n"
          "![Delta sweep](figures/table2_delta" + ("_quick" if setup.quick else "") + ".png)")
    _plot(setup, results)
    write_outputs(setup, "table2", {"seeds": seeds, "deltas": results}, md)


def _plot(setup, results) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stereojax.data.io import atomic_output

    deltas = [r["delta"] for r in results]
    fig, ax = plt.subplots(figsize=(5.5, 3.6), dpi=120)
    for key, label, colour in (("bad3", "> 3 px", "tab:red"), ("bad2", "> 2 px", "tab:blue")):
        stats = [mean_std([s[key] for s in r["seeds"]]) for r in results]
        ax.errorbar(deltas, [m for m, _ in stats], yerr=[s for _, s in stats], marker="o", capsize=3,
                    color=colour, label=label)
        for r in results:
            ax.scatter([r["delta"]] * len(r["seeds"]), [s[key] for s in r["seeds"]], s=8, color=colour, alpha=0.35)
    ax.set_xlabel("Delta (margin of the relaxed loss; 0 = plain cross-entropy)")
    ax.set_ylabel("KITTI 2015 error, % of GT pixels")
    ax.set_title(f"Delta sweep, mean ± std over {len(results[0]['seeds'])} seed(s)")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    figs = setup.out / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    with atomic_output(figs / ("table2_delta" + ("_quick" if setup.quick else "") + ".png")) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


if __name__ == "__main__":
    main()
