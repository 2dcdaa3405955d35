"""Would a bfloat16 head make the learned chain faster on this CPU? (issue 26: "perhaps a bf16
head where the processor supports it (measure it)").

The head's work is a stack of dense layers on every (pixel, candidate) pair. This times the
shipped `kitti2015` head (its real weights; input = the split first layer's sum of the two
towers' projections, as the chain runs it) on N pairs in float32 and in bfloat16 (weights and
activations; accumulation as XLA does it), with XLA:CPU's default code generator and with its
oneDNN and XNNPACK paths, each in a fresh process. It also reports how far the bfloat16
similarities are from the float32 ones. The CPU's flags (avx512_bf16, amx_bf16) are listed.

Command:  .venv/bin/python experiments/investigations/bf16_head.py   (about 2 min here)
-> experiments/results/bf16_head.{json,md}
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

OUT = Path(__file__).resolve().parents[1] / "results"
N = 65536
FLAGS = {"default": "", "oneDNN": "--xla_cpu_use_onednn=true", "XNNPACK": "--xla_cpu_use_xnnpack=true"}

CHILD = r"""
import json, sys, time
import jax, jax.numpy as jnp, numpy as np
import stereojax
from stereojax.models.registry import shipped_weights

model = stereojax.load_model(shipped_weights("kitti2015"))
head = model.variables["params"]["head"]
names = ["dense1", "dense2", "dense3", "out"]          # the layers after the split first one
layers = [(np.asarray(head[k]["kernel"]), np.asarray(head[k]["bias"])) for k in names]
n = int(sys.argv[1])
x = np.random.default_rng(0).normal(size=(n, layers[0][0].shape[0])).astype(np.float32)


def run(x, dt):
    h = jax.nn.relu(x).astype(dt)
    for i, (w, b) in enumerate(layers):
        h = h @ w.astype(dt) + b.astype(dt)
        if i < len(layers) - 1:
            h = jax.nn.relu(h)
    return jax.nn.sigmoid(h.astype(jnp.float32))


def best_of(f, x, repeats=5):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f(x).block_until_ready()
        times.append(time.perf_counter() - t0)
    return min(times)


out = {}
ys = {}
for name, dt in (("float32", jnp.float32), ("bfloat16", jnp.bfloat16)):
    f = jax.jit(lambda x, dt=dt: run(x, dt))
    ys[name] = np.asarray(f(x))
    out[name] = best_of(f, x)
diff = np.abs(ys["bfloat16"] - ys["float32"])
out["max_abs_diff"], out["mean_abs_diff"] = float(diff.max()), float(diff.mean())
out["layers"] = [list(w.shape) for w, _ in layers]
print(json.dumps(out))
"""


def main():
    flags = sorted(set(open("/proc/cpuinfo").read().split()) & {"avx512_bf16", "amx_bf16", "amx_tile", "avx512f"})
    rows = {}
    for label, flag in FLAGS.items():
        env = {**os.environ, "XLA_FLAGS": flag, "STEREOJAX_CACHE_DIR": "off"}
        out = subprocess.run([sys.executable, "-c", CHILD, str(N)], env=env, capture_output=True, text=True, check=True)
        rows[label] = json.loads(out.stdout.strip().splitlines()[-1])
        r = rows[label]
        print(f"{label:>8}: float32 {r['float32']:.3f} s, bfloat16 {r['bfloat16']:.3f} s", flush=True)
    import jax

    layers = next(iter(rows.values()))["layers"]
    data = {"n_pairs": N, "cpu_flags": flags, "jax": jax.__version__, "layers": layers, "rows": rows}
    OUT.joinpath("bf16_head.json").write_text(json.dumps(data, indent=2) + "\n")
    lines = ["# A bfloat16 head on this CPU (issue 26)", "",
             f"The shipped `kitti2015` head after its split first layer ({' → '.join([str(layers[0][0])] + [str(s[1]) for s in layers])}) "
             f"on {N} (pixel, candidate) pairs, best of 5 warm runs, each code path in a fresh process; "
             f"jax {jax.__version__}, 2 CPU cores with {', '.join(flags) or 'no bf16 flags'}. "
             "`python experiments/investigations/bf16_head.py`.", "",
             "| XLA:CPU path | float32 s | bfloat16 s | bf16 / f32 | max / mean abs. difference of the similarity |",
             "|---|---|---|---|---|"]
    for label, r in rows.items():
        lines.append(f"| {label} ({FLAGS[label] or 'no flag'}) | {r['float32']:.3f} | {r['bfloat16']:.3f} | "
                     f"{r['bfloat16'] / r['float32']:.2f} | {r['max_abs_diff']:.4f} / {r['mean_abs_diff']:.5f} |")
    lines += ["", "A ratio at or above 1 means bfloat16 buys no time here: XLA:CPU does not turn these dots "
              "into AMX/AVX512-BF16 kernels in this version, so the head stays float32."]
    OUT.joinpath("bf16_head.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT / 'bf16_head.md'}")


if __name__ == "__main__":
    main()
