"""The README's picture of a Rerun recording (issue 54): what `predict --rerun FILE.rrd` logs for
one KITTI 2015 pair, read back from the .rrd with Rerun's own reader and drawn with matplotlib
(this machine has no display for Rerun's viewer: its --headless screenshot needs a GPU context).

Command:  .venv/bin/python experiments/rerun_figure.py [--frame 000021] [--method census]
-> docs/figures/rerun_example.jpg (and the recording in runs/rerun_example/)
"""

import argparse
from pathlib import Path

import numpy as np

from common import DEFAULT_DATA, ROOT  # noqa: E402

from stereojax.app.cli import main as cli  # noqa: E402


def read_entities(rrd: Path) -> dict:
    """entity path -> {column: first row's value} of a recording."""
    from rerun.chunk import RrdReader

    out = {}
    for chunk in RrdReader(rrd).stream():
        rb = chunk.to_record_batch()
        out.setdefault(chunk.entity_path, {}).update({n: rb.column(n).to_pylist()[0] for n in rb.schema.names
                                                      if ":" in n})       # the components, not the time columns
    return out


def main():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frame", default="000021")
    ap.add_argument("--method", default="census")
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    args = ap.parse_args()
    root = Path(args.data) / "kitti2015" / "training"
    run = ROOT / "runs" / "rerun_example"
    rrd = run / "kitti.rrd"
    code = cli(["predict", str(root / "image_2" / f"{args.frame}_10.png"), str(root / "image_3" / f"{args.frame}_10.png"),
                "--out", str(run / "out"), "--overwrite", "--method", args.method, "--baseline", "0.5372", "--focal",
                "721.5377", "--ply", "--max-depth", "60", "--rerun", str(rrd)])
    assert code == 0
    ent = read_entities(rrd)
    cam = ent["/world/camera"]
    w, h = cam["Pinhole:resolution"][0]
    img = ent["/world/camera/image"]
    fmt = img["Image:format"][0]
    left = np.frombuffer(bytes(img["Image:buffer"][0]), np.uint8).reshape(fmt["height"], fmt["width"], -1)
    depth = np.frombuffer(bytes(ent["/world/camera/depth"]["DepthImage:buffer"][0]), np.float32).reshape(int(h), int(w))
    pts = np.asarray(ent["/world/points"]["Points3D:positions"], np.float32).reshape(-1, 3)
    cols = np.asarray(ent["/world/points"]["Points3D:colors"], np.uint32)
    rgb = np.stack([(cols >> 24) & 255, (cols >> 16) & 255, (cols >> 8) & 255], -1) / 255.0
    keep = np.random.default_rng(0).choice(len(pts), min(len(pts), 80000), replace=False)
    fig = plt.figure(figsize=(13, 6.2))
    ax = fig.add_subplot(2, 2, 1)
    ax.imshow(left)
    ax.set_title("world/camera/image", fontsize=9)
    ax.axis("off")
    ax = fig.add_subplot(2, 2, 3)
    im = ax.imshow(np.where(depth > 0, depth, np.nan), cmap="turbo_r", vmin=0, vmax=60)
    ax.set_title("world/camera/depth (m)", fontsize=9)
    ax.axis("off")
    fig.colorbar(im, ax=ax, fraction=0.025)
    ax = fig.add_subplot(1, 2, 2, projection="3d")
    p = pts[keep]
    ax.scatter(p[:, 0], p[:, 2], -p[:, 1], c=rgb[keep], s=0.3, linewidths=0)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_zlabel("-y (m)")
    ax.view_init(elev=14, azim=-70)
    ax.set_xlim(-20, 20)
    ax.set_ylim(0, 60)
    ax.set_zlim(-3, 12)
    ax.set_box_aspect((40, 60, 15))
    ax.set_title(f"world/points ({len(pts)} coloured points)", fontsize=9)
    fig.suptitle(f"What `predict --rerun` logs for KITTI 2015 {args.frame} ({args.method}), read back from the .rrd "
                 "(drawn with matplotlib; open the file in Rerun for the interactive view)", fontsize=10)
    fig.tight_layout()
    out = ROOT / "docs" / "figures" / "rerun_example.jpg"
    fig.savefig(out, dpi=80, pil_kwargs={"quality": 85})
    print(out, out.stat().st_size)


if __name__ == "__main__":
    main()
