"""Figures 5-8 — qualitative results on KITTI 2015: for each frame one PNG with the left and right
images, the predicted disparity, the KITTI-style error map and the depth map (Z = B·f/d), from the
shipped KITTI 2015 model (downsize head, relaxed loss) in the default `preset("learned")` chain.

Command:  make figures   (= .venv/bin/python experiments/figures.py [--frames 000021 000024 ...])
          .venv/bin/python experiments/figures.py --quick      (one cropped frame, seconds)
Running time here (2 cores): 6.5 min for the 4 default frames (pruned mode, K = 32; about
1 min a frame warm, more with other jobs on the cores).
Writes experiments/results/figures/fig_<frame>.png and experiments/results/figures.{json,md}
(per frame: > 3 px error, share of over-exposed pixels, and why the frame was chosen). The
default frames are validation frames (never trained on) picked by looking at them: 000021
(bridge and tree shadows, over-exposed hoarding), 000022 (long shadow across an intersection),
000024 (ordinary traffic), 000029 (over-exposed sky, deep shadow).
"""

import argparse

import numpy as np

from common import QUICK_CROP, Setup, load_sample, add_common_args, md_table, shrink, write_outputs

import stereojax
from stereojax.data.io import colorize_disparity, error_map, write_png
from stereojax.data.depth import disparity_to_depth
from stereojax.metrics import evaluate
from stereojax.models.registry import load_model, shipped_weights

#: KITTI's rectified focal length and baseline (representative values, as in KITTI's own
#: calib_cam_to_cam files of 2011_09_26: f = 721.5 px, B = 0.533 m, as in depth_example.py); the
#: shared data has no calibration files
KITTI_FOCAL, KITTI_BASELINE = 721.5377, 0.5327
NOTES = {"000021": "bridge and tree shadows on the road, over-exposed white hoarding",
         "000022": "long shadow across an intersection, textureless road",
         "000024": "ordinary traffic scene (cars at several depths)",
         "000029": "over-exposed sky (15 % saturated pixels), deep shadow on the right"}


def main():
    ap = add_common_args(argparse.ArgumentParser(description=__doc__.splitlines()[0]))
    ap.add_argument("--frames", nargs="+", default=list(NOTES))
    ap.add_argument("--scale", type=float, default=0.5,
                    help="size of the saved panels (default 0.5: about 0.6 MB a frame instead of 2.5 MB)")
    args = ap.parse_args()
    setup = Setup.from_args(args)
    model = load_model(shipped_weights("kitti2015"))
    frames = args.frames[:1] if setup.quick else args.frames
    figs = setup.out / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    rows, data = [], []
    for frame in frames:
        s = load_sample(str(setup.data), "kitti2015", frame, "noc")
        if setup.quick:
            s = s.crop(*QUICK_CROP)
        md = setup.max_disp("kitti2015", s)
        disp = stereojax.disparity(s.left, s.right, stereojax.preset("learned", md), params=model)
        m = evaluate(disp, s.gt, s.gt_valid)
        grey = s.left.mean(-1) if s.left.ndim == 3 else s.left
        over = 100.0 * float((grey >= 250).mean())
        panel = shrink(_panel(s, disp, md), args.scale)
        name = f"fig_{frame}" + ("_quick" if setup.quick else "") + ".png"
        write_png(figs / name, panel)
        rows.append([frame, NOTES.get(frame, ""), f"{m['bad3']:.2f}", f"{m['epe']:.2f}", f"{over:.1f}",
                     f"![{frame}](figures/{name})"])
        data.append({"frame": frame, "note": NOTES.get(frame, ""), "bad3": m["bad3"], "epe": m["epe"],
                     "overexposed_percent": over, "png": f"figures/{name}"})
        print(f"  {frame}: > 3 px {m['bad3']:.2f} % -> {figs / name}", flush=True)
    md = ("# Figures 5-8 — KITTI 2015 validation frames, shipped model\n\n"
          "Each PNG, top to bottom: left image, right image, predicted disparity (turbo colour map, "
          "near = red), KITTI-style error map (GT pixels only; blue = small error, orange/red = "
          "> 3 px outliers), depth Z = B·f/d (f = 721.5 px, B = 0.533 m; near = bright, clipped "
          "at 80 m).\n\n"
          + md_table(["frame", "case", "> 3 px %", "EPE px", "over-exposed %", "figure"], rows))
    write_outputs(setup, "figures", {"frames": data}, md)


def _panel(s, disp, max_disp) -> np.ndarray:
    """u8[5H, W, 3] RGB: left, right, disparity, error map, depth."""
    import cv2

    def rgb(img):
        return np.repeat(img[..., None], 3, -1) if img.ndim == 2 else img[..., :3]

    colour = colorize_disparity(disp, float(s.gt[s.gt_valid].max()) if s.gt_valid.any() else max_disp)
    err = error_map(disp, s.gt, s.gt_valid)
    z = disparity_to_depth(disp, KITTI_BASELINE, KITTI_FOCAL)
    z = np.nan_to_num(np.clip(z, 0, 80.0), nan=80.0, posinf=80.0)
    depth = cv2.applyColorMap((255 * (1 - z / 80.0)).astype(np.uint8), cv2.COLORMAP_INFERNO)[..., ::-1]
    tiles = [rgb(np.asarray(s.left, np.uint8)), rgb(np.asarray(s.right, np.uint8)), colour, err, depth]
    return np.concatenate(tiles, axis=0)


if __name__ == "__main__":
    main()
