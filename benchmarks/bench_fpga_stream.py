"""Frames per second of the simulated FPGA Harris stream at 640x480.

Streams ``--frames`` 640x480 images (KITTI 07 frames resized to 640x480, or a
seeded noise texture with ``--synthetic``) through ``FpgaHarrisStream``, one
push and one read per frame, and reports wall-clock frames/s of the
simulation (target >= 20) next to the simulated hardware rate (pixel clock /
(pixels + blanking) per frame). Points are checked against
``HarrisDetector(arithmetic="fixed")`` on the first frame.

JSON (default ``benchmarks/results/fpga_stream.json``) and its PNG beside it.

    python benchmarks/bench_fpga_stream.py [--frames 40] [--synthetic] [--quick] [--out FILE.json]
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from frontend.fpga_stream import FpgaHarrisStream, FpgaTiming  # noqa: E402
from frontend.harris import HarrisConfig, HarrisDetector  # noqa: E402
from frontend.image import load_gray  # noqa: E402
import entry  # noqa: E402  (beside this script: --quick sizes, argparse types)

KITTI = ROOT.parent / "shared" / "data" / "kitti07" / "image_0"
SHAPE = (480, 640)


def frames(n, synthetic, seed=0):
    if synthetic or not KITTI.is_dir():
        rng = np.random.default_rng(seed)
        out = []
        for _ in range(n):
            small = rng.standard_normal((SHAPE[0] // 6, SHAPE[1] // 6))
            img = cv2.resize(small, SHAPE[::-1], interpolation=cv2.INTER_NEAREST)
            out.append(np.clip(128 + 50 * img, 0, 255).astype(np.uint8))
        return out, "synthetic"
    files = sorted(KITTI.glob("*.png"))[:n]
    return [cv2.resize(load_gray(f), SHAPE[::-1], interpolation=cv2.INTER_AREA) for f in files], \
        "kitti07 resized"


def plot(result: dict, per_frame_ms: list[float], out: Path) -> Path:
    """Simulation time of each frame, with the hardware's frame period and the target."""
    from plotting import Panel, save_figure  # beside this script

    k = list(range(len(per_frame_ms)))
    return save_figure(out, f"Simulated FPGA Harris stream, {SHAPE[1]}x{SHAPE[0]}, "
                            f"{result['frames']} frames ({result['source']})", [
        Panel("time per frame", "frame", "time per frame [ms]",
              {f"simulation (mean {result['fps']:.1f} frames/s)": (k, per_frame_ms)},
              targets={f"simulated hardware ({result['hardware_fps']:.1f} frames/s)":
                       1e3 / result["hardware_fps"],
                       f"target {result['target_fps']:g} frames/s": 1e3 / result["target_fps"]})],
        ncols=1)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=entry.count, default=40)
    ap.add_argument("--synthetic", action="store_true")
    ap.add_argument("--quick", action="store_true", help="4 frames")
    ap.add_argument("--out", type=entry.output_file, default=ROOT / "benchmarks" / "results" / "fpga_stream.json",
                    help="JSON to write (and its PNG beside it)")
    args = ap.parse_args(argv)
    if args.quick:
        entry.quick_sizes(ap, argv, args, frames=4)

    imgs, source = frames(args.frames, args.synthetic)
    cfg = HarrisConfig(arithmetic="fixed")
    timing = FpgaTiming()
    stream = FpgaHarrisStream(cfg, timing)
    ok = None
    per_frame = []
    n_points = 0
    t_all = time.perf_counter()
    for i, img in enumerate(imgs):
        t = time.perf_counter()
        stamp = stream.push_frame(img, stream.next_start_s())
        feats = stream.read(stamp)
        per_frame.append(time.perf_counter() - t)
        n_points += len(feats)
        if i == 0:
            ref = HarrisDetector(cfg).detect(img)
            ok = bool(np.array_equal(ref.xy_px, feats.xy_px)
                      and np.array_equal(ref.response, feats.response))
    wall = time.perf_counter() - t_all - 0.0
    fps = len(imgs) / sum(per_frame)
    hw_fps = 1.0 / timing.frame_period_s(SHAPE)
    print(f"FPGA Harris stream simulation, {SHAPE[1]}x{SHAPE[0]}, {len(imgs)} frames ({source})")
    print(f"{'quantity':<36}{'value':>12}")
    print(f"{'simulation frames/s (mean)':<36}{fps:>12.1f}")
    print(f"{'simulation ms/frame (median)':<36}{np.median(per_frame) * 1e3:>12.2f}")
    print(f"{'simulation ms/frame (best)':<36}{min(per_frame) * 1e3:>12.2f}")
    print(f"{'simulated hardware frames/s':<36}{hw_fps:>12.2f}")
    print(f"{'points per frame (mean)':<36}{n_points / len(imgs):>12.1f}")
    print(f"{'bit-identical to fixed (frame 0)':<36}{str(ok):>12}")
    print(f"target >= 20 frames/s: {'met' if fps >= 20 else 'NOT met'}")
    result = {"shape": list(SHAPE), "frames": len(imgs), "source": source, "fps": fps,
              "ms_per_frame_median": float(np.median(per_frame) * 1e3),
              "ms_per_frame_best": float(min(per_frame) * 1e3), "wall_s": wall,
              "hardware_fps": hw_fps, "points_per_frame": n_points / len(imgs),
              "bit_identical_frame0": ok, "target_fps": 20.0}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, result, indent=2)
    plot(result, [1e3 * t for t in per_frame], args.out)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
