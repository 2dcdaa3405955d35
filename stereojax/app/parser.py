"""The ``stereojax`` command line declared: its sub-commands, their options and help.

Declarations only; :mod:`stereojax.app.cli` runs the command that was parsed (``args.command``).
"""

from __future__ import annotations

import argparse

from stereojax import __version__
from stereojax.data.datasets import DEFAULT_DATA, KITTI_MAX_DISP

DEFAULT_MAX_DISP = KITTI_MAX_DISP     # 228, the KITTI search range of the data layer


def _unit(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}")
    return value


class _Formatter(argparse.HelpFormatter):
    """argparse's help, except that ``--disp-range`` reads ``MIN MAX | auto`` (not the repeated
    ``MIN MAX|auto [MIN MAX|auto ...]`` that its one-or-more values would show)."""

    def _format_args(self, action, default_metavar):
        if action.dest == "disp_range":
            return "MIN MAX | auto"
        return super()._format_args(action, default_metavar)


class _OneLineParser(argparse.ArgumentParser):
    """Usage errors (unknown option, ``--max-disp 1.5``) as one line on stderr, exit code 2."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kwargs)

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``stereojax`` parser: every command's arguments, declared one ``add_argument`` each.
    Long because it is a list of declarations (no logic: the commands live in :mod:`stereojax.app.cli`);
    split per command it would only scatter the shared options."""
    p = _OneLineParser(prog="stereojax", description="Stereo matching in JAX: disparity and depth from a "
                       "rectified pair. The matching cost is learned (an MC-CNN-style network, shipped "
                       "models for KITTI and Middlebury) or classical (census, SAD); then cross-based "
                       "aggregation, semi-global matching and refinement.")
    p.add_argument("--version", action="version", version=f"stereojax {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    def add_method(sp):
        sp.add_argument("--method", default="best", choices=["best", "learned", "census", "sad"],
                        help="matching cost (default: best = learned with the shipped model for this "
                        "kind of input -- KITTI-like wide frames: KITTI 2015 model, others: Middlebury "
                        "model -- or census when that model is not shipped)")
        sp.add_argument("--weights", help="network checkpoint for --method learned/best, or the name of "
                        "a shipped model (kitti2015_compact, kitti2015 = the paper's full network, middlebury)")
        sp.add_argument("--exact-head", action="store_true", help="learned cost: run the head at every "
                        "disparity instead of the candidates (slow on a CPU; its chain settings were never "
                        "searched)")
        sp.add_argument("--config", help="JSON file with a full StereoConfig (overrides the chain "
                        "settings of --method; its cost.method must fit --method)")
        sp.add_argument("--cascade", type=float, metavar="Q", help="the cascade: the student (--weights, default "
                        "kitti2015_compact) everywhere, and the full network (--cascade-weights, default the "
                        "model best picks) at the share Q (0 < Q <= 1, e.g. 0.2) of pixels where the student "
                        "is least confident")
        sp.add_argument("--cascade-weights", help="--cascade: the full network (a checkpoint or a shipped name)")
        sp.add_argument("--scene", default="auto", choices=["auto", "road", "indoor"], help="--method best: the "
                        "model for road frames (KITTI 2015) or indoor scenes (Middlebury); auto (default): road "
                        "when the frame is at least 2.5 times as wide as high, or by --dataset")

    def add_kernels(sp):
        sp.add_argument("--kernels", choices=["auto", "native", "xla"], help="the kernels of SGM, CBCA and the "
                        "census cost: native (the C++ kernels on the CPU, an error where they did not load), xla "
                        "(the JAX kernels) or auto (default, or a --config file's kernels: native where they "
                        "loaded, else JAX, said on the first line)")

    def add_devices(sp):
        sp.add_argument("--devices", type=int, help="spread the frames over this many local devices, "
                        "one frame per device at a time (default: all; the results equal one device's)")

    sp = sub.add_parser("predict", help="disparity (and depth) of one rectified pair, or of many: "
                        "two folders, a KITTI training/ or testing/ folder, or a list of pairs")
    sp.add_argument("inputs", nargs="*", metavar="INPUT",
                    help="LEFT RIGHT (two images: one pair; two folders: pairs matched by file name), "
                    "or one KITTI training/ or testing/ folder, or one text file of 'LEFT RIGHT' lines")
    sp.add_argument("--pairs", help="text file with one 'LEFT RIGHT' pair per line")
    sp.add_argument("--out", required=True, help="output folder (a batch writes OUT/<frame>/...)")
    sp.add_argument("--max-disp", type=int, help="number of disparities searched, 0 <= d < N (default: a --config "
                    "file's max_disp, else 228 = KITTI's; see the README on choosing it; given beside --config, "
                    "this one wins)")
    sp.add_argument("--disp-range", nargs="+", help="search the disparities MIN <= d < MAX "
                    "instead of 0 .. max-disp - 1 (MIN may be negative); auto: measured on the pair (a quick "
                    "dense probe over the window its feature matches allow), printed and written to frame.json")
    sp.add_argument("--baseline", type=float, help="baseline in metres (for depth)")
    sp.add_argument("--focal", type=float, help="focal length in pixels (for depth)")
    sp.add_argument("--doffs", type=float, default=0.0, help="x-difference of principal points (Middlebury)")
    sp.add_argument("--calib", metavar="FILE | LEFT.yaml,RIGHT.yaml", help="calibration file for depth: KITTI "
                    "calib_cam_to_cam.txt or calib/<frame>.txt, Middlebury calib.txt, OpenCV YAML or JSON with K and "
                    "baseline (m); with --rectify, a raw stereo calibration: `stereojax calibrate`'s file, OpenCV's "
                    "stereoCalibrate output (YAML, XML or JSON: M1/K1, D1, M2/K2, D2, R, T), Kalibr's camchain.yaml, "
                    "or two ROS camera_info files as LEFT.yaml,RIGHT.yaml")
    sp.add_argument("--rectify", action="store_true", help="rectify each raw pair with the raw stereo calibration of "
                    "--calib before matching (OpenCV stereoRectify, maps built once per image size); writes "
                    "left_rectified.png, right_rectified.png and rectification.json (R1, R2, P1, P2, Q)")
    sp.add_argument("--frame", default="rectified", choices=["rectified", "original"], help="--rectify: the "
                    "point cloud in the rectified left camera's frame (default) or rotated into the original (raw) "
                    "left camera's; depth stays on the rectified pixel grid")
    sp.add_argument("--ply", action="store_true", help="also write a coloured point cloud (needs a calibration; "
                    "refused without one)")
    sp.add_argument("--max-depth", type=float, metavar="M", help="no depth (0) in depth.npy/depth.png and no point "
                    "in points.ply beyond M metres (default: none; depth.png itself holds at most 255.99 m)")
    sp.add_argument("--tile", default="auto", choices=["auto", "off"], help="a pair too large for the memory limit: "
                    "auto computes it in horizontal bands (default), off refuses it (exit code 6)")
    sp.add_argument("--check-rectified", default="warn", choices=["warn", "error", "off"], help="check with "
                    "feature matches that the pair is rectified and not swapped: warn (default), error, off")
    sp.add_argument("--min-confidence", type=_unit, default=0.0, metavar="T", help="no disparity or depth "
                    "(0 in the PNGs) where the confidence (confidence.png) is below T in [0, 1] (default 0: all)")
    sp.add_argument("--overwrite", action="store_true", help="a batch computes every frame again (default: "
                    "frames already complete in --out with the same method, model, settings and inputs are kept)")
    sp.add_argument("--verify", action="store_true", help="a batch reads the SHA-256 of every kept frame's files "
                    "again (default: their sizes are checked); a frame that fails is computed again")
    sp.add_argument("--sequence", action="store_true", help="the pairs are consecutive frames of one camera, in "
                    "name order: each frame searches near the previous frame's confident disparities (falling back "
                    "to the whole range at a scene cut or where the prior fails), and OUT/sequence.mp4 shows them")
    sp.add_argument("--fps", type=float, default=10.0, help="--sequence: frames per second of the video (default 10, "
                    "KITTI's)")
    sp.add_argument("--rerun", metavar="FILE.rrd", help="also log every frame to a Rerun recording (open it with "
                    "`rerun FILE.rrd` or app.rerun.io): the left image, disparity, confidence, depth with the camera as "
                    "a pinhole and the coloured point cloud; a --sequence on a timeline with its prior and fallbacks "
                    "as text events (needs pip install \"stereojax[viewer]\")")
    sp.add_argument("--rerun-serve", action="store_true", help="as --rerun, to Rerun's web viewer served from this "
                    "machine (the URL is printed; the command waits for Ctrl-C once done)")
    sp.add_argument("--ray", metavar="ADDRESS", help="compute the batch on a Ray cluster: HOST:PORT, ray://HOST:PORT, "
                    "or auto (RAY_ADDRESS, else a new local cluster); same outputs and resume as a local batch "
                    "(needs pip install \"stereojax[ray]\"; OUT must be a folder every node sees)")
    sp.add_argument("--ray-workers", type=int, metavar="N", help="with --ray: this many workers (default: one per "
                    "GPU, else one per 2 CPUs of the cluster)")
    add_devices(sp)
    add_method(sp)
    add_kernels(sp)

    sp = sub.add_parser("calibrate", help="calibrate a raw stereo pair from chessboard views (OpenCV "
                        "stereoCalibrate) for predict --calib FILE --rectify")
    sp.add_argument("left", help="the left views: a folder, or a quoted glob pattern such as 'cal/left*.jpg'")
    sp.add_argument("right", help="the right views, paired with the left ones in sorted order")
    sp.add_argument("--board", default="9x6", help="inner corners of the chessboard, COLSxROWS (default 9x6)")
    sp.add_argument("--square", type=float, default=1.0, help="side of a square, in the unit depth should have "
                    "(metres, e.g. 0.025; default 1: depth in squares)")
    sp.add_argument("--out", default="stereo.yaml", help="the calibration file to write (.yaml, .yml, .xml or "
                    ".json; default stereo.yaml)")

    sp = sub.add_parser("evaluate", help="score the pipeline on KITTI 2012/2015 or Middlebury")
    sp.add_argument("--data", required=True, help="data root (e.g. ../shared/data/kitti2015/training)")
    sp.add_argument("--dataset", required=True, choices=["kitti2015", "kitti2012", "middlebury"])
    sp.add_argument("--frames", help="e.g. 000021-000030 or 21,22 (default: all)")
    sp.add_argument("--gt", default="auto", choices=["auto", "noc", "occ", "both"], help="ground truth: auto "
                    "(default: non-occluded pixels where the data has them, else all pixels; one line says which), "
                    "noc, occ (all pixels), or both scored apart")
    sp.add_argument("--fill", default="interpolate", choices=["interpolate", "error"],
                    help="pixels without estimate: KITTI background interpolation, or count as errors")
    sp.add_argument("--max-disp", type=int, help="default: 228 for KITTI, ndisp/GT for Middlebury")
    sp.add_argument("--sgbm", action="store_true",
                    help="also score OpenCV StereoSGBM, left-padded and unpadded, in the same run")
    sp.add_argument("--out", default="out/evaluate", help="output folder (an evaluation of the same settings "
                    "there is continued: frames already scored are taken from OUT/frames/)")
    sp.add_argument("--overwrite", action="store_true", help="score every frame again")
    sp.add_argument("--verify", action="store_true", help="read the SHA-256 of every reused frame's files again "
                    "(default: their sizes are checked)")
    add_devices(sp)
    add_method(sp)
    add_kernels(sp)

    sp = sub.add_parser("demo", help="run the built-in Middlebury Motorcycle pair and print its errors")
    sp.add_argument("--out", default="out/demo")
    sp.add_argument("--max-disp", type=int, help="default: the sample's disparity range")
    add_method(sp)
    add_kernels(sp)

    sp = sub.add_parser("train", help="train the matching network on patch pairs (CPU)")
    sp.add_argument("--data", required=True, help="data root (e.g. ../shared/data)")
    sp.add_argument("--dataset", default="kitti2015", choices=["kitti2015", "kitti2012", "middlebury"])
    sp.add_argument("--frames", default="000001-000020", help="training frames or scenes (comma list)")
    sp.add_argument("--val-frames", help="validation frames (patch error)")
    sp.add_argument("--preset", default="cpu", choices=["cpu", "paper", "tiny"], help="cpu (default): the "
                    "paper's head on a tower of 64 maps, 50 000 steps (hours on 2 cores); paper: 112 maps and the "
                    "paper's schedule, 240 000 steps; tiny: 8 maps for 12 steps, for tests -- it learns nothing")
    sp.add_argument("--checkpoint-every", type=int, metavar="N", help="write OUT/checkpoint.msgpack every N steps "
                    "(default: the preset's, 1000 for cpu); SIGINT/SIGTERM also write one")
    sp.add_argument("--head", choices=["downsize", "uniform", "cosine"], help="the network's head (default "
                    "downsize, or --init's)")
    sp.add_argument("--loss", choices=["bce", "relaxed", "hinge"], help="default: relaxed, or hinge for cosine")
    sp.add_argument("--delta", type=float, help="margin of the relaxed loss (default 0.05)")
    sp.add_argument("--steps", type=int)
    sp.add_argument("--seed", type=int)
    sp.add_argument("--config", help="JSON TrainConfig (overrides the preset options)")
    sp.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.msgpack")
    sp.add_argument("--augment", action="store_true", help="MC-CNN-style patch augmentation (rotation, "
                    "scale, shear, brightness and contrast; right patches get their own small difference)")
    sp.add_argument("--init", help="start from these weights (a checkpoint or a shipped model name) "
                    "instead of random ones, with their network (tower and head) and their card's chain "
                    "settings, marked as inherited; the optimiser and schedule start afresh")
    sp.add_argument("--lr", type=float, help="initial learning rate (default: the preset's, 0.02)")
    sp.add_argument("--features", type=int, help="feature maps of the tower (default: the preset's, 64 for cpu)")
    sp.add_argument("--widths", help="hidden widths of a dense head, comma separated (default: the head's, "
                    "512,384,256,128 for downsize); e.g. 64,32 for a compressed network")
    sp.add_argument("--distill", help="teacher network (a checkpoint or a shipped model name): distil its "
                    "similarities beside the loss on the labels")
    sp.add_argument("--distill-weight", type=float, default=1.0, help="weight of the distillation term (default 1)")
    sp.add_argument("--devices", type=int, help="data-parallel over this many devices (default: all); "
                    "the batch must divide by it")
    sp.add_argument("--out", required=True)

    sp = sub.add_parser("tune", help="search the chain settings of your own checkpoint on your own frames "
                        "with ground truth, and write them as its card (NAME.json beside NAME.msgpack)")
    sp.add_argument("--weights", required=True, help="the checkpoint to tune (not a shipped model)")
    sp.add_argument("--data", required=True, help="data root (e.g. ../shared/data/kitti2015/training)")
    sp.add_argument("--dataset", required=True, choices=["kitti2015", "kitti2012", "middlebury"])
    sp.add_argument("--frames", required=True, help="training frames with ground truth, e.g. 000001-000020 (never "
                    "the frames you will report)")
    sp.add_argument("--space", default="small", choices=["small", "full", "local"], help="small (default): P1, P2, "
                    "CBCA passes, LR tolerance, median; full: 11 settings; local: one step around the current ones")
    sp.add_argument("--rounds", type=int, default=1, help="passes over the settings (default 1)")
    sp.add_argument("--max-disp", type=int, help="default: 228 for KITTI, ndisp/GT for Middlebury")

    sp = sub.add_parser("bench", help="time every stage on a KITTI-sized frame (and OpenCV SGBM)")
    sp.add_argument("--out", default="experiments/results")
    sp.add_argument("--repeats", type=int, default=3)
    sp.add_argument("--data", default=DEFAULT_DATA, help="shared data root with KITTI 2015 000021 (default "
                    f"{DEFAULT_DATA}; without it the built-in sample, resized)")
    sp.add_argument("--max-disp", type=int, default=DEFAULT_MAX_DISP)
    return p
