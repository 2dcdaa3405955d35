"""The `make bench` report: experiments/results/bench.json (written by `stereojax bench`,
:mod:`stereojax.app.bench`) against the targets the project's issues set, as
experiments/results/bench.md. Each target line says met, or by how much it is missed and which
stage holds it. The accuracy the targets of issue 26 are read against comes from other results
files (:func:`accuracy_records`).

Command:  .venv/bin/python experiments/bench_report.py [--results experiments/results]
(a second; `make bench` runs it after the measurements)
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from stereojax.app.bench import CASCADE, CASCADE_PROGRAMS, LEARNED, NETWORK_STAGES
from stereojax.chain import STAGES
from stereojax.data.io import atomic_output

RESULTS = Path(__file__).resolve().parent / "results"


#: the targets of issue 16, checked by format_bench
TARGETS = {"best_s": 6.0, "best_stretch_s": 3.0, "census_x_sgbm": 20.0, "peak_rss_bytes": 2e9,
           "second_process_extra_s": 5.0}
#: the targets of issue 25 (ratios to OpenCV SGBM timed in the same run; peak RSS of a predict process)
BAND_TARGETS = {"census_x_sgbm": 10.0, "compact_x_sgbm": 25.0, "best_chain_x_sgbm": 15.0,
                "peak_rss_gib": 1.2}


#: the targets of issue 26 (`best` in two seconds): ratios to OpenCV SGBM of the same run, `best`'s
#: share of Pandora's time (make bench-anchors), peak RSS of a `best` predict process, make demo's
#: warm computation, validation > 3 px on KITTI 2015 000021-000030
BEST_TARGETS = {"best_x_sgbm": 30.0, "stretch_x_sgbm": 15.0, "stretch_val": 3.92, "pandora_share": 0.2,
                "peak_rss_gib": 1.2, "demo_s": 5.0, "val": 3.97}


#: the targets of issue 36 (one pass through the chain): ratios to SGBM of the same run; peak RSS of
#: a census and a compact predict process with the compiled chain read from the cache
CHAIN_TARGETS = {"census_x_sgbm": 6.0, "compact_x_sgbm": 15.0, "best_chain_x_sgbm": 8.0, "peak_rss_gib": 1.0}

#: the stages whose cost entries per second the report sets against OpenCV's (issue 36)
RATE_STAGES = ("coarse pass (bands)", "matching cost", "candidate chain", "CBCA before SGM", "SGM",
               "CBCA after SGM", "right view + WTA")


def _profiles(r: dict, xla: bool = False) -> list[tuple[str, dict]]:
    """(chain, stage profile) of every profiled chain: the default kernels', or (``xla``) the
    JAX kernels' where the run also timed them (``census_stages_xla``, a profile's ``stages_xla``)."""
    if xla:
        out = [("census", r.get("census_stages_xla"))]
        out += [(m, p.get("stages_xla")) for m, p in r["profiles"].items()]
    else:
        out = [("census", r["census_stages"])] + [(m, p["stages"]) for m, p in r["profiles"].items()]
    return [(m, st) for m, st in out if st]


def entry_rates(r: dict, xla: bool = False) -> list[dict]:
    """Cost entries per second of the band kernels of each profiled chain against OpenCV SGBM's
    (its H x W x D entries in its measured time, cost and every path included): one row per
    (chain, stage) of :data:`RATE_STAGES` that ran, with ``x_opencv`` the time per entry
    relative to OpenCV's (``xla``: the stage profiles of the JAX kernels, where measured)."""
    h, w = r["shape"]
    sgbm_rate = h * w * r["max_disp"] / r["sgbm_padded_s"]
    rows = []
    for chain_name, stages in _profiles(r, xla):
        for name in RATE_STAGES:
            t = stages.get(name)
            if not t or not t.get("entries") or t["warm_s"] <= 0:
                continue
            if chain_name != "census" and name == "matching cost":
                continue          # the learned head: network time, not a band kernel
            rate = t["entries"] / t["warm_s"]
            rows.append({"chain": chain_name, "stage": name, "entries": t["entries"], "warm_s": t["warm_s"],
                         "rate": rate, "x_opencv": sgbm_rate / rate})
    return rows


def _held(r: dict, stages: dict, chain_name: str) -> str:
    """Which stage of a profile holds the chain most (the tower and head of a learned chain left
    out), with its entries per second against OpenCV's, and the slowest stages."""
    rates = {(row["chain"], row["stage"]): row for row in entry_rates(r)}
    name, v = max(((n, v) for n, v in stages.items() if n not in NETWORK_STAGES or chain_name == "census"),
                  key=lambda kv: kv[1]["warm_s"])
    rate = rates.get((chain_name, name))
    per = (f", {rate['rate'] / 1e6:.0f} M entries/s, {rate['x_opencv']:.1f}× OpenCV's time per entry"
           if rate else "")
    return f"Held most by {name} ({v['warm_s']:.2f} s{per}); slowest: {_top(stages)}."


def chain_targets(r: dict) -> list[str]:
    """The lines on issue 36's targets: met, or by how much they are missed and which stage holds it."""
    sg, chains, t = r["sgbm_padded_s"], r["chains"], CHAIN_TARGETS

    def held(stages: dict, chain_name: str) -> str:
        return _held(r, stages, chain_name)

    out = []
    if "warm_s" in chains.get("census", {}):
        _target_line(out, "census chain, × SGBM", chains["census"]["warm_s"] / sg, t["census_x_sgbm"], "×",
                     held(r["census_stages"], "census"))
    prof = r["profiles"].get("kitti2015_compact")
    if prof and "warm_s" in chains.get("kitti2015_compact", {}):
        _target_line(out, "`kitti2015_compact`, × SGBM", chains["kitti2015_compact"]["warm_s"] / sg,
                     t["compact_x_sgbm"], "×", held(prof["stages"], "kitti2015_compact"))
    prof = r["profiles"].get("kitti2015")
    if prof and "warm_s" in chains.get("kitti2015", {}):
        net = _network_s(prof)
        rest = chains["kitti2015"]["warm_s"] - net
        _target_line(out, "the chain around `kitti2015`'s tower and head, × SGBM", rest / sg, t["best_chain_x_sgbm"],
                     "×", f"{rest:.2f} s of {chains['kitti2015']['warm_s']:.2f} s (tower + head {net:.2f} s). "
                     + held(prof["stages"], "kitti2015"))
    for m in ("census", "kitti2015_compact"):
        p = r["processes"].get(m)
        if p:
            _target_line(out, f"peak RSS of a `{m}` predict process, compiled chain from the cache",
                         p["cache_hit"]["peak_rss_gib"], t["peak_rss_gib"], " GiB",
                         f"Cold cache: {p['cold']['peak_rss_gib']:.2f} GiB; the rest is the interpreter, jax and "
                         "XLA's buffers of the chain.")
    return out


def rate_table(r: dict) -> list[str]:
    """The markdown table of :func:`entry_rates`: with the JAX kernels' rates of the same run beside
    the default kernels' where the run measured them (issue 51), else one set of columns."""
    h, w = r["shape"]
    n = h * w * r["max_disp"]
    lines = [f"OpenCV SGBM: {n / 1e6:.0f} M entries ({w}x{h}x{r['max_disp']}) in {r['sgbm_padded_s']:.3f} s = "
             f"{n / r['sgbm_padded_s'] / 1e6:.0f} M entries/s (its cost, every path and its WTA).", ""]
    xla = {(x["chain"], x["stage"]): x for x in entry_rates(r, xla=True)}
    if not xla:
        lines += ["| chain | stage | M entries | warm s | M entries/s | × OpenCV's time per entry |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {x['chain']} | {x['stage']} | {x['entries'] / 1e6:.1f} | {x['warm_s']:.3f} | "
                  f"{x['rate'] / 1e6:.0f} | {x['x_opencv']:.1f} |" for x in entry_rates(r)]
        return lines
    k = _kernels(r)
    lines += [f"| chain | stage | M entries | {k} warm s | {k} M entries/s | {k} × OpenCV's time per entry | "
              "xla warm s | xla M entries/s | xla × OpenCV's time per entry |", "|---|---|---|---|---|---|---|---|---|"]
    for x in entry_rates(r):
        y = xla.get((x["chain"], x["stage"]))
        other = [f"{y['warm_s']:.3f}", f"{y['rate'] / 1e6:.0f}", f"{y['x_opencv']:.1f}"] if y else ["", "", ""]
        cells = [x["chain"], x["stage"], f"{x['entries'] / 1e6:.1f}", f"{x['warm_s']:.3f}", f"{x['rate'] / 1e6:.0f}",
                 f"{x['x_opencv']:.1f}", *other]
        lines.append(("| " + " | ".join(cells) + " |").replace("  ", " "))
    return lines


#: the targets of issue 51 (native CPU kernels): ratios to SGBM of the same run (the chain around
#: `kitti2015`'s tower and head as the sum of its stage profile's other stages); each stage profile
#: adds up to its chain's warm time within this share; every native kernel's time per cost entry
#: against OpenCV's; peak RSS of a census and a compact predict process with the compiled chain
#: from the cache
NATIVE_TARGETS = {"census_x_sgbm": 3.0, "compact_x_sgbm": 12.0, "best_chain_x_sgbm": 4.0, "profile_gap_pct": 10.0,
                  "x_opencv": 3.0, "peak_rss_gib": 1.0}

#: compile time (s) of each whole chain in a fresh process without the cache before the native
#: kernels: the `make bench` of 2026-12-06 (commit 95d8fbc), the run issue 51 quotes as "now"
COMPILE_BEFORE = {"census": 7.733, "kitti2015_compact": 13.034, "kitti2015": 12.561, "cascade": 15.432}
COMPILE_BEFORE_RUN = "`make bench` of 2026-12-06, before the native kernels"


def _kernels(r: dict) -> str:
    """The kernels of the run's default chains, "native" or "xla" (a bench.json without the
    ``kernels`` entry predates the native kernels: "xla")."""
    return (r.get("kernels") or {}).get("kernels", "xla")


def kernels_line(r: dict) -> str:
    """The kernels of the run, in words (bench.md's first line and issue 51's section)."""
    rec = r.get("kernels")
    if rec is None:
        return "JAX (XLA) kernels (this bench.json predates the native kernels)"
    if rec["kernels"] == "native":
        both = " and the JAX kernels beside them" if r.get("chains_xla") or r.get("census_stages_xla") else ""
        return f"native C++ kernels on the CPU (XLA FFI){both}"
    return "JAX (XLA) kernels" + (f": the native kernels did not load ({rec['reason']})" if rec.get("reason") else
                                  f" (setting {rec.get('setting', 'xla')!r})")


def _sum_s(stages: dict, network: bool = True) -> float:
    """Warm seconds of a stage profile's stages (``network=False``: without the tower and the head)."""
    return sum(v["warm_s"] for n, v in stages.items() if network or n not in NETWORK_STAGES)


def native_targets(r: dict) -> list[str]:
    """The lines on issue 51's targets: met, or by how much they are missed and which stage holds
    it; the JAX kernels' numbers of the same run beside the native ones where measured. A
    bench.json from before the native kernels (no ``kernels`` entry, no ``*_xla`` keys) gives the
    same lines for its JAX kernels, without the comparison."""
    sg, chains, t = r["sgbm_padded_s"], r["chains"], NATIVE_TARGETS
    xla_chains = r.get("chains_xla") or {}
    profiles = r["profiles"]
    stages_of = {"census": r["census_stages"], **{m: p["stages"] for m, p in profiles.items() if m in LEARNED}}
    xla_stages_of = dict(_profiles(r, xla=True))
    native = _kernels(r) == "native"
    out = [f"Kernels of this run: {kernels_line(r)}." + ("" if native else
           " No native kernel ran, so every line below is the JAX kernels'."), ""]

    def beside(m: str) -> str:
        c = xla_chains.get(m, {})
        return (f"With the JAX kernels in this run: {c['warm_s']:.2f} s = {c['warm_s'] / sg:.1f}× SGBM."
                if "warm_s" in c else "")

    for m, label, goal in (("census", "census chain", t["census_x_sgbm"]),
                           ("kitti2015_compact", "`kitti2015_compact`", t["compact_x_sgbm"])):
        if "warm_s" in chains.get(m, {}) and m in stages_of:
            warm = chains[m]["warm_s"]
            _target_line(out, f"{label}, × SGBM", warm / sg, goal, "×", _held(r, stages_of[m], m),
                         info=f"{warm:.2f} s against SGBM's {sg:.3f} s. {beside(m)}")
    prof = profiles.get("kitti2015")
    if prof:
        rest, net = _sum_s(prof["stages"], network=False), _network_s(prof)
        whole = chains.get("kitti2015", {}).get("warm_s")
        minus = f"; the chain's warm time minus them: {whole - net:.2f} s" if whole else ""
        _target_line(out, "the chain around `kitti2015`'s tower and head (its stage profile without them), × SGBM",
                     rest / sg, t["best_chain_x_sgbm"], "×",
                     _held(r, {n: v for n, v in prof["stages"].items() if n not in NETWORK_STAGES}, "kitti2015"),
                     info=f"{rest:.2f} s in the other stages (tower + head {net:.2f} s{minus}).")
    best = r["best"]
    for m in dict.fromkeys(("census", "kitti2015_compact", best)):
        stages, whole = stages_of.get(m), chains.get(m, {}).get("warm_s")
        if not stages or not whole:
            continue
        total = _sum_s(stages)
        gap = 100 * abs(total - whole) / whole
        label = f"`best` (= `{m}`)" if m == best else ("census" if m == "census" else f"`{m}`")
        info = f"The stages {total:.2f} s, the chain {whole:.2f} s (fresh process)"
        xs, xc = xla_stages_of.get(m), xla_chains.get(m, {}).get("warm_s")
        if xs and xc:
            info += f"; with the JAX kernels {_sum_s(xs):.2f} s against {xc:.2f} s"
        where = (f"{whole - total:.2f} s of the chain sit in no stage" if whole > total else
                 f"the stages jitted alone take {total - whole:.2f} s more than the chain")
        _target_line(out, f"the gap between the stage profile of {label} and its chain's warm time",
                     gap, t["profile_gap_pct"], " %", f"{where}.", info=info + ".")
    xla_rates = {}
    for x in entry_rates(r, xla=True):
        xla_rates.setdefault(x["stage"], []).append(x)
    rows = {}
    for x in entry_rates(r):
        rows.setdefault(x["stage"], []).append(x)
    for name in RATE_STAGES:
        if name not in rows:
            continue
        worst = max(rows[name], key=lambda x: x["x_opencv"])
        info = ", ".join(f"{x['chain']} {x['x_opencv']:.1f}× ({x['rate'] / 1e6:.0f} M entries/s)" for x in rows[name])
        if name in xla_rates:
            info += "; the JAX kernels: " + ", ".join(f"{x['chain']} {x['x_opencv']:.1f}×" for x in xla_rates[name])
        _target_line(out, f"{name}: time per cost entry, × OpenCV's", worst["x_opencv"], t["x_opencv"], "×",
                     f"Slowest in {worst['chain']}.", info=info + ".")
    for m in ("census", "kitti2015_compact"):
        p = r["processes"].get(m)
        if p:
            _target_line(out, f"peak RSS of a `{m}` predict process, compiled chain from the cache",
                         p["cache_hit"]["peak_rss_gib"], t["peak_rss_gib"], " GiB",
                         info=f"Cold cache: {p['cold']['peak_rss_gib']:.2f} GiB.")
    order = list(COMPILE_BEFORE)
    for m in sorted(chains, key=lambda m: (order.index(m) if m in order else len(order), m)):
        c = chains[m]
        if "compile_s" not in c:
            continue
        before, x = COMPILE_BEFORE.get(m), xla_chains.get(m, {})
        parts = [f"the JAX kernels in this run: {x['compile_s']:.1f} s"] if "compile_s" in x else []
        cold = r["processes"].get("best" if m == best else m, {}).get("cold", {})
        if "compile_s" in cold:
            parts.append(f"`stereojax predict` with a cold cache: {cold['compile_s']:.1f} s")
        if before is None:
            rest = f" ({'; '.join(parts)})" if parts else ""
            out.append(f"* compile time of the `{m}` chain (fresh process, no cache): {c['compile_s']:.1f} s{rest}.")
            continue
        verdict = ("no worse than before." if round(c["compile_s"], 1) <= round(before, 1) else
                   f"**worse than before**, {c['compile_s'] - before:.1f} s over.")
        rest = f" {'; '.join(parts)}." if parts else ""
        out.append(f"* compile time of the `{m}` chain (fresh process, no cache), ≤ {before:.1f} s ({COMPILE_BEFORE_RUN}):"
                   f" {c['compile_s']:.1f} s — {verdict}{rest[:2].upper() + rest[2:] if rest else ''}")
    out.append("* the scores (`stereojax evaluate` on 000021–000030, `make demo`'s errors) are not measured by "
               "`make bench`.")
    return out


def accuracy_records(out_dir: Path) -> dict:
    """The accuracy records the targets of issue 26 are read against (other runs, not this one):
    the full KITTI network's and the chosen student's validation > 3 px, and the Middlebury
    student's fold mean, each with the file it comes from (missing files are left out)."""
    out = {}

    def read(name):
        f = Path(out_dir) / name
        return json.loads(f.read_text()) if f.is_file() else None

    dd, fin, mid = read("dense_distill.json"), read("dense_distill_final.json"), read("middlebury_folds_student.json")
    if dd:
        out["kitti2015"] = {"val": dd["full"]["val"], "seconds": dd["full"]["seconds"], "source": "dense_distill.md"}
    if fin:
        out["student"] = {"name": fin["point"], "val": fin["val"], "seconds": fin["seconds"], "limit": fin["best_limit"],
                          "becomes_best": fin["becomes_best"], "source": "dense_distill_final.md"}
    curve = read("cascade_curve_validation.json")
    if curve:
        q = f"cascade {100 * CASCADE[2]:g} %"
        rows = curve["frames"]
        if rows and q in rows[0]["bad3"]:
            out["cascade"] = {"val": sum(r["bad3"][q] for r in rows) / len(rows), "frames": len(rows),
                              "full_val": sum(r["bad3"]["full"] for r in rows) / len(rows),
                              "source": "cascade_curve.md"}
    if mid:
        out["middlebury_student"] = {"bad3": mid["mean"]["learned"]["bad3"], "limit": mid["student_bar"],
                                     "seconds": mid["seconds"]["learned"], "becomes_best": mid["becomes_best"],
                                     "source": "middlebury_folds_student.md"}
    return out


def _ordered(stages: dict) -> list:
    """The rows of a stage profile in the chain's order (JSON round trips sort the keys)."""

    order = [s.name for s in STAGES]
    return sorted(stages.items(), key=lambda kv: order.index(kv[0]) if kv[0] in order else len(order))


def _arch(net: dict) -> str:
    return f"tower {net['features']} maps, head {'-'.join(map(str, net['widths']))}"


def _target_line(out: list, name: str, value: float, goal: float, unit: str, why: str = "", info: str = "") -> None:
    """Append one target's line to ``out``: met, or by how much it is missed and why (``info``:
    the numbers behind it, said either way)."""
    ok = value <= goal
    out.append((f"* {name} ≤ {goal:g}{unit}: {value:.2f}{unit} — " + ("met." if ok else
                f"**not met**, {value - goal:.2f}{unit} over. {why}").rstrip() + f" {info.strip()}").rstrip())


def _top(stages: dict, n: int = 3) -> str:
    """The ``n`` slowest stages, "name s, ..."."""
    return ", ".join(f"{name} {v['warm_s']:.2f} s" for name, v in
                     sorted(stages.items(), key=lambda kv: -kv[1]["warm_s"])[:n])


def _network_s(prof: dict) -> float:
    """Warm seconds of a learned chain's tower and head stages (its profile's)."""
    return sum(v["warm_s"] for name, v in prof["stages"].items() if name in NETWORK_STAGES)


def best_targets(r: dict) -> list[str]:
    """The lines on issue 26's targets: met, or by how much they are missed and why."""
    sg, t, best = r["sgbm_padded_s"], BEST_TARGETS, r["best"]
    chain, prof = r["chains"].get(best, {}), r["profiles"].get(best)
    acc = r.get("accuracy") or {}
    student, val = acc.get("student"), acc.get(best, {}).get("val")
    out = []
    if student:
        verdict = "stays the full network" if not student["becomes_best"] else "is that student"
        short = (f"The fastest student ({student['name']}) scores {student['val']:.2f} % against the bound "
                 f"{student['limit']:g} % at {student['seconds']:.2f} s ({student['source']}), so `best` {verdict}")
    else:
        short = "No student record (experiments/results/dense_distill_final.json)"
    if "warm_s" in chain and prof:
        net = _network_s(prof)
        _target_line(out, f"`best` (= `{best}`), × SGBM", chain["warm_s"] / sg, t["best_x_sgbm"], "×",
                     f"{chain['warm_s']:.2f} s, of which tower + head {net:.2f} s ({prof['network_tflop']:.1f} TFLOP "
                     f"at {prof['evals_per_pixel']:g} head evaluations per pixel) and the chain around them "
                     f"{chain['warm_s'] - net:.2f} s. {short}.")
        if val is not None:
            stretch = chain["warm_s"] / sg <= t["stretch_x_sgbm"] and val <= t["stretch_val"]
            out.append(f"* stretch, ≤ {t['stretch_x_sgbm']:g}× SGBM at ≤ {t['stretch_val']:g} %: "
                       f"{chain['warm_s'] / sg:.0f}× at {val:.2f} % — " + ("met." if stretch else "**not met**."))
    a = r.get("anchors")
    if a and a.get("pandora_s"):
        _target_line(out, "`best` / Pandora's time (make bench-anchors, its own run)", a["best_s"] / a["pandora_s"],
                     t["pandora_share"], "×", f"`best` {a['best_s']:.1f} s, Pandora {a['pandora_s']:.1f} s "
                     "(anchors.md); the same head as above.")
    p = r["processes"].get("best")
    if p:
        _target_line(out, "peak RSS of a `best` predict process (cold cache)", p["cold"]["peak_rss_gib"],
                     t["peak_rss_gib"], " GiB", "See issue 25's line above.")
    demo, mid = r.get("demo") or {}, acc.get("middlebury_student")
    if "warm_s" in demo:
        h, w = demo["shape"]
        why = (f"{demo['model']}, {w}x{h}, {demo['max_disp']} disparities, with the confidence map; compiling "
               f"{demo['compile_s']:.1f} s.")
        if mid:
            why += (f" The Middlebury student's fold mean {mid['bad3']:.2f} % > 3 px misses the bound "
                    f"{mid['limit']:g} % ({mid['source']}, {mid['seconds']:.1f} s per scene), so the demo "
                    "keeps the full network.")
        _target_line(out, "`make demo`'s computation after compiling (fresh process)", demo["warm_s"],
                     t["demo_s"], " s", why)
    if val is not None:
        _target_line(out, f"validation > 3 px of `best` (KITTI 2015 000021-000030, band chain; "
                     f"{acc[best]['source']})", val, t["val"], " %",
                     "The full network on the band chain (3.92 % over the full range).")
    return out


#: the targets of issue 38 (the full network where it matters): the cascade's ratio to SGBM of the
#: same run at validation <= 4.08 %, `best`'s share of Pandora's time, make demo's computation,
#: peak RSS of a `best` predict process with the compiled chain read from the cache
CASCADE_TARGETS = {"best_x_sgbm": 60.0, "stretch_x_sgbm": 30.0, "val": 4.08, "pandora_share": 0.33, "demo_s": 8.0,
                   "peak_rss_gib": 1.5}


def cascade_targets(r: dict) -> list[str]:
    """The lines on issue 38's targets: the cascade of the bench (:data:`stereojax.app.bench.CASCADE`)
    as `best` would run it, and `best` as it is."""
    sg, t, out = r["sgbm_padded_s"], CASCADE_TARGETS, []
    casc, prof = r["chains"].get("cascade", {}), r["profiles"].get("cascade")
    acc = (r.get("accuracy") or {}).get("cascade")
    best = r["chains"].get(r["best"], {})
    if "warm_s" in casc and prof:
        st = {k: v["warm_s"] for k, v in prof["stages"].items()}
        names = CASCADE_PROGRAMS
        where = (f"{casc['warm_s']:.2f} s: the student to its confidence {st[names[0]] + st[names[1]]:.2f} s, "
                 f"then the full network and the chain again {st[names[2]]:.2f} s (its tower alone "
                 f"{st[names[3]]:.2f} s)")
        val = f"; validation > 3 px {acc['val']:.2f} % ({acc['source']})" if acc else ""
        _target_line(out, f"the cascade at q = {100 * casc['share']:g} % (`{casc['student']}` + `{casc['full']}`), "
                     "× SGBM", casc["warm_s"] / sg, t["best_x_sgbm"], "×", where + val + ".")
        if acc:
            ok = acc["val"] <= t["val"]
            out.append(f"* its validation > 3 px ≤ {t['val']:g} %: {acc['val']:.2f} % — "
                       + ("met." if ok else f"**not met**, {acc['val'] - t['val']:.2f} points over."))
        if "warm_s" in best:
            out.append(f"* the rule's time (≤ a third of the full network, same run): {casc['warm_s']:.2f} s against "
                       f"{best['warm_s'] / 3:.2f} s — " + ("met." if casc["warm_s"] <= best["warm_s"] / 3 else
                                                          f"**not met**, {casc['warm_s'] - best['warm_s'] / 3:.2f} s over "
                                                          f"(`best` runs `{r['best']}`)."))
    if "warm_s" in best:
        _target_line(out, f"`best` (= `{r['best']}`), × SGBM", best["warm_s"] / sg, t["best_x_sgbm"], "×",
                     f"`best` runs `{r['best']}` (the rule: experiments/results/cascade_curve.md).")
    a = r.get("anchors")
    if a and a.get("pandora_s"):
        _target_line(out, "`best` / Pandora's time (make bench-anchors, its own run)", a["best_s"] / a["pandora_s"],
                     t["pandora_share"], "×", f"`best` {a['best_s']:.1f} s, Pandora {a['pandora_s']:.1f} s.")
    demo = r.get("demo") or {}
    if "warm_s" in demo:
        _target_line(out, "`make demo`'s computation after compiling (fresh process)", demo["warm_s"], t["demo_s"],
                     " s", f"{demo['model']}: no Middlebury student is shipped, so the demo has no cascade.")
    p = r["processes"].get("best")
    if p:
        _target_line(out, "peak RSS of a `best` predict process, compiled chain from the cache",
                     p["cache_hit"]["peak_rss_gib"], t["peak_rss_gib"], " GiB",
                     "The full network's chain; the rest is XLA's buffers and the interpreter.")
    return out


def band_targets(r: dict) -> list[str]:
    """The lines on issue 25's targets (ratios to SGBM of this run; peak RSS of predict processes)."""
    sg, chains, t = r["sgbm_padded_s"], r["chains"], BAND_TARGETS
    cfg = (r.get("config_census") or {}).get("band") or {}
    k = cfg.get("width", 0)
    h, w = r["shape"]
    out = []
    if "warm_s" in chains.get("census", {}):
        _target_line(out, "census chain, × SGBM", chains["census"]["warm_s"] / sg, t["census_x_sgbm"], "×",
                      f"Largest stages: {_top(r['census_stages'])}; the band kernels gather each neighbour's band "
                      f"(K = {k}: f32[H, W, K] is {h * w * max(k, 1) * 4 / 1e6:.0f} MB) where the full range shifts slices.")
    prof = r["profiles"].get("kitti2015_compact")
    if prof and "warm_s" in chains.get("kitti2015_compact", {}):
        _target_line(out, "`kitti2015_compact`, × SGBM", chains["kitti2015_compact"]["warm_s"] / sg, t["compact_x_sgbm"], "×",
                      f"Largest stages: {_top(prof['stages'])}.")
    prof = r["profiles"].get("kitti2015")
    if prof and "warm_s" in chains.get("kitti2015", {}):
        net = _network_s(prof)
        rest = chains["kitti2015"]["warm_s"] - net
        _target_line(out, "`kitti2015` without its tower and head, × SGBM", rest / sg, t["best_chain_x_sgbm"], "×",
                      f"{rest:.2f} s of {chains['kitti2015']['warm_s']:.2f} s (tower + head {net:.2f} s); "
                      f"largest other stages: {_top({n: v for n, v in prof['stages'].items() if n not in NETWORK_STAGES})}.")
    for m, p in r["processes"].items():
        peak = p["cold"]["peak_rss_gib"]
        _target_line(out, f"peak RSS of a `{m}` predict process (cold cache), GiB", peak, t["peak_rss_gib"], " GiB",
                      f"With the compiled chain read from the cache: {p['cache_hit']['peak_rss_gib']:.2f} GiB "
                      "(compiling takes about 0.6 GiB); the rest is XLA's buffers of the chain.")
    return out


def format_bench(r: dict) -> str:
    """The markdown report of :func:`run_bench`'s result."""
    sg = r["sgbm_padded_s"]
    chains, profiles, t = r["chains"], r["profiles"], TARGETS
    h, w = r["shape"]

    def ratio(x):
        return f"{x / sg:.0f}x"

    def target(ok):
        return "met" if ok else "**not met**"

    xla_chains = r.get("chains_xla") or {}
    lines = [f"# Benchmark: {r['frame']}, {w}x{h}, {r['max_disp']} disparities, {r['cpu_cores']} CPU cores, "
             f"jax {r['jax']} ({r['backend']}), {r.get('machine', '')}"
             + (f"; kernels: {kernels_line(r)}" if "kernels" in r else ""), "",
             "All numbers from one run of `make bench` (`stereojax bench`); OpenCV StereoSGBM timed at the "
             "start and the end of the run (the faster of the two, so that a slow SGBM run never flatters a ratio).", "",
             "## Warm time per frame (after compilation), ratio to OpenCV SGBM", "",
             "| method | network | head evaluations / pixel | warm s | × SGBM | target |", "|---|---|---|---|---|---|",
             f"| OpenCV StereoSGBM (MODE_SGBM_3WAY, left-padded) | | | {sg:.3f} | 1x | |"]
    for which in LEARNED:
        chain, prof = chains[which], profiles[which]
        if "warm_s" not in chain:
            continue
        is_best = which == r["best"]
        ok = chain["warm_s"] <= t["best_s"]
        goal = (f"`best` ≤ {t['best_s']:g} s: {target(ok)}; stretch ≤ {t['best_stretch_s']:g} s: "
                f"{target(chain['warm_s'] <= t['best_stretch_s'])}" if is_best else
                f"(≤ {t['best_s']:g} s: {'yes' if ok else 'no'}; not `best`)")
        label = f"`--method best` = `{which}`" if is_best else f"`--weights {which}`"
        lines.append(f"| stereojax {label} | {_arch(prof['net'])} | {prof['evals_per_pixel']:g} | "
                     f"{chain['warm_s']:.2f} | {ratio(chain['warm_s'])} | {goal} |")
        x = xla_chains.get(which, {})
        if "warm_s" in x:
            lines.append(f"| stereojax `--weights {which}`, JAX kernels (`--kernels xla`) | {_arch(prof['net'])} | "
                         f"{prof['evals_per_pixel']:g} | {x['warm_s']:.2f} | {ratio(x['warm_s'])} | |")
    full = profiles["kitti2015"]
    ex = full["exact"]
    lines.append(f"| stereojax `kitti2015`, exact head (extrapolated from 8 disparities) | "
                 f"{_arch(full['net'])} | {r['max_disp']} | {ex['chain_s']:.0f} | {ratio(ex['chain_s'])} | |")
    casc = chains.get("cascade", {})
    if "warm_s" in casc:
        lines.append(f"| stereojax cascade: `{casc['student']}` everywhere, `{casc['full']}` at the "
                     f"{100 * casc['share']:g} % least confident pixels | both | 16 + {100 * casc['share']:g} % × 16 | "
                     f"{casc['warm_s']:.2f} | {ratio(casc['warm_s'])} | (not `best`: cascade_curve.md) |")
    census = chains["census"]
    if "warm_s" in census:
        lines.append(f"| stereojax census chain | | | {census['warm_s']:.2f} | {ratio(census['warm_s'])} | "
                     f"≤ {t['census_x_sgbm']:g}x: {target(census['warm_s'] <= t['census_x_sgbm'] * sg)} |")
    x = xla_chains.get("census", {})
    if "warm_s" in x:
        lines.append(f"| stereojax census chain, JAX kernels (`--kernels xla`) | | | {x['warm_s']:.2f} | "
                     f"{ratio(x['warm_s'])} | |")
    a = r.get("anchors")
    if a and a.get("pandora_s"):
        lines += ["", f"CNES Pandora {a.get('pandora_version', '')} (MC-CNN-fast, Middlebury weights, + libsgm), "
                  f"timed by `make bench-anchors` in a run of its own beside stereojax and SGBM: Pandora "
                  f"{a['pandora_s']:.1f} s, `best` {a['best_s']:.1f} s"
                  + (f", `kitti2015_compact` {a['compact_s']:.1f} s" if "compact_s" in a else "")
                  + f", SGBM {a['sgbm_s']:.3f} s; so `best` is {a['best_s'] / a['pandora_s']:.2f}× Pandora's time"
                  + (f" and `kitti2015_compact` {a['compact_s'] / a['pandora_s']:.2f}×" if "compact_s" in a else "")
                  + " ([anchors.md](anchors.md))."]
    if all("entries" in v for v in r["census_stages"].values()):
        lines += ["", "## The targets of issue 51 (native CPU kernels), met or missed, and why", ""]
        lines += native_targets(r)
        both = bool(entry_rates(r, xla=True))
        lines += ["", "## Cost entries per second of the band kernels" + (", native and JAX kernels side by side,"
                                                                           if both else ",") + " against OpenCV's", ""]
        lines += rate_table(r)
        lines += ["", "## The targets of issue 36 (one pass through the chain), met or missed, and why", ""]
        lines += chain_targets(r)
    if "cascade" in chains and "cascade" in profiles:
        lines += ["", "## The targets of issue 38 (the full network where it matters), met or missed, and why", ""]
        lines += cascade_targets(r)
        lines += ["", f"Where the cascade's time goes (q = {100 * profiles['cascade']['share']:g} %, each program "
                  "timed alone, warm):", "", "| program | warm s |", "|---|---|"]
        lines += [f"| {k} | {profiles['cascade']['stages'][k]['warm_s']:.2f} |" for k in CASCADE_PROGRAMS]
    lines += ["", "## The targets of issue 25 (bands), met or missed, and why", ""]
    lines += band_targets(r)
    lines += ["", "## The targets of issue 26 (`best` in two seconds), met or missed, and why", ""]
    lines += best_targets(r)
    lines += ["", "## Processes: compile once, peak memory", "",
              "| method | first process (cold cache) s | second process (cache hit) s | compile in 1st / 2nd s "
              "| peak RSS GiB | targets |", "|---|---|---|---|---|---|"]
    for m, p in r["processes"].items():
        cold, hit = p["cold"], p["cache_hit"]
        warm = chains[r["best"] if m == "best" else m].get("warm_s", float("nan"))
        checks = [f"2nd ≤ warm + {t['second_process_extra_s']:g} s: "
                  f"{target(hit['wall_s'] <= warm + t['second_process_extra_s'])}"]
        peak = max(cold["peak_rss_gib"], hit["peak_rss_gib"])
        if m == "best":
            checks.append(f"peak RSS ≤ {t['peak_rss_bytes'] / 1e9:g} GB: {target(peak * 2 ** 30 <= t['peak_rss_bytes'])}")
        lines.append(f"| {m} | {cold['wall_s']:.1f} | {hit['wall_s']:.1f} | {cold.get('compile_s', float('nan')):.1f} / "
                     f"{hit.get('compile_s', float('nan')):.1f} | {peak:.2f} | {'; '.join(checks)} |")
    lines += ["", "(wall time of the whole `stereojax predict` process: interpreter start, imports, loading, "
              "compiling or reading the compiled chain from the cache, the run, writing outputs.)"]
    for which in LEARNED:
        prof = profiles[which]
        ex = prof["exact"]
        lines += ["", f"## Where the time of `{which}` goes (each stage jitted alone, warm)", ""]
        lines += stage_table(prof["stages"], prof.get("stages_xla"), _kernels(r), 2)
        lines += ["", f"Network: {prof['network_tflop'] * 1e3:.0f} GFLOP per frame, of which the head after its "
                  f"split first layer {prof['head_tflop'] * 1e3:.0f} GFLOP at {prof['evals_per_pixel']:g} evaluations "
                  f"per pixel; its exact head {ex['tflop']:.1f} TFLOP, {ex['warm_s']:.0f} s extrapolated "
                  f"({ex['gflop_s']:.0f} GFLOP/s; dense f32 matmul peak here {r['matmul_gflop_s']:.0f} GFLOP/s)."]
    lines += ["", "## Census chain stages (each jitted alone, warm)", ""]
    lines += stage_table(r["census_stages"], r.get("census_stages_xla"), _kernels(r), 3)
    lines += ["", "Peak RSS of a process that compiles and runs the chain (no cache): " + ", ".join(
        f"{m} {c.get('peak_rss_gib', float('nan')):.2f} GiB" for m, c in chains.items())
        + ("; with the JAX kernels: " + ", ".join(f"{m} {c.get('peak_rss_gib', float('nan')):.2f} GiB"
                                                  for m, c in xla_chains.items()) if xla_chains else "") + ".", ""]
    return "\n".join(lines)


def stage_table(stages: dict, stages_xla: dict | None, kernels: str, digits: int) -> list[str]:
    """A stage profile as a markdown table in the chain's order, with the sum of its stages; with
    the JAX kernels' profile of the same run beside it when there is one (issue 51)."""
    cw, cc = digits, digits - 1
    if not stages_xla:
        lines = ["| stage | warm s | compile s |", "|---|---|---|"]
        lines += [f"| {k} | {v['warm_s']:.{cw}f} | {v['compile_s']:.{cc}f} |" for k, v in _ordered(stages)]
        lines.append(f"| sum of the stages | {_sum_s(stages):.{cw}f} | "
                     f"{sum(v['compile_s'] for v in stages.values()):.{cc}f} |")
        return lines
    lines = [f"| stage | {kernels} warm s | {kernels} compile s | xla warm s | xla compile s |", "|---|---|---|---|---|"]
    names = [k for k, _ in _ordered({**stages_xla, **stages})]

    def cells(d: dict, k: str) -> str:
        v = d.get(k)
        return f"{v['warm_s']:.{cw}f} | {v['compile_s']:.{cc}f}" if v else " | "
    lines += [f"| {k} | {cells(stages, k)} | {cells(stages_xla, k)} |" for k in names]
    lines.append(f"| sum of the stages | {_sum_s(stages):.{cw}f} | {sum(v['compile_s'] for v in stages.values()):.{cc}f} | "
                 f"{_sum_s(stages_xla):.{cw}f} | {sum(v['compile_s'] for v in stages_xla.values()):.{cc}f} |")
    return lines


def write_report(results: Path = RESULTS) -> Path:
    """bench.md from bench.json and the accuracy records beside it."""
    r = json.loads((results / "bench.json").read_text())
    r["accuracy"] = accuracy_records(results)
    with atomic_output(results / "bench.md") as tmp:
        Path(tmp).write_text(format_bench(r))
    return results / "bench.md"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", default=str(RESULTS), help="the folder with bench.json (default: %(default)s)")
    print(f"-> {write_report(Path(ap.parse_args().results))}")


if __name__ == "__main__":
    main()
