"""``run --intrinsics estimate`` on real photos whose camera is known: the camera it
estimates, how its rounds settle from both starts, and the run's ATE with it beside the
run's with the calibrated camera.

Data no one on the team made, each with a calibration the estimate never sees:

- **the Lund door** (12 photos, 1296x1936): COLMAP's SIMPLE_RADIAL camera (``f``, ``k1``)
  and its reconstruction as the truth (its own unit of length);
- **KITTI 07** ``image_0/`` (160 frames, 1226x370, read as a plain folder): ``calib.txt``'s
  rectified camera (``k1 = 0``) and the ground-truth poses; the run's config is
  ``benchmarks/kitti07_visual.toml``, as the README's KITTI command.

Each runs as a user runs it, ``graphslam run --intrinsics estimate --odometry none
--ground-truth ...``, then with the calibrated camera; the ATE is after a Sim(3) fit, as a
share of the path.

    python benchmarks/bench_self_calibration.py [--quick]

``--quick``: the Lund door only. Writes ``benchmarks/results/self_calibration.json`` (or
``--out``) and a PNG beside it: each start's focal length per round against the
calibration's.
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

from plotting import Panel, save_figure  # noqa: E402

from graphslam.cli.main import main as graphslam  # noqa: E402
import entry  # noqa: E402  (beside this script: its argparse types)

DATA = HERE.parent.parent / "shared" / "data"


def _cases(data: Path, work: Path, quick: bool) -> list[dict]:
    """Each photo set (``quick``: the Lund door only): its images, the calibrated camera
    as an intrinsics file, its truth and the run's extra arguments."""
    lund = data / "lund_door"
    cam = [ln.split() for ln in (lund / "colmap_ground_truth" / "cameras.txt").read_text().splitlines()
           if ln.strip() and not ln.startswith("#")][0]
    f, cx, cy, k = map(float, cam[4:8])  # SIMPLE_RADIAL: f cx cy k (COLMAP's pixel centres)
    cases = [
        {
            "name": "lund_door",
            "images": lund / "images",
            "intrinsics": lund / "colmap_ground_truth" / "cameras.txt",
            "truth": lund / "colmap_ground_truth" / "images.txt",
            "calibrated": {"f_px": f, "k1": k, "cx_px": cx - 0.5, "cy_px": cy - 0.5},
            "extra": [],
        },
    ]
    if quick:
        return cases
    kitti = data / "kitti07"
    p0 = [ln for ln in (kitti / "calib.txt").read_text().splitlines() if ln.startswith("P0:")][0].split()[1:]
    return cases + [
        {
            "name": "kitti07",
            "images": kitti / "image_0",
            "intrinsics": _kitti_camera(p0, work),
            "truth": kitti / "poses.txt",
            "calibrated": {"f_px": float(p0[0]), "k1": 0.0, "cx_px": float(p0[2]), "cy_px": float(p0[6])},
            "extra": ["--config", str(HERE / "kitti07_visual.toml")],
        },
    ]


def _kitti_camera(p0: list[str], work: Path) -> Path:
    """calib.txt's P0 as an intrinsics file (a plain folder takes no calib.txt)."""
    path = work / "kitti07_image_0_K.txt"
    path.write_text(f"{p0[0]} {p0[5]} {p0[2]} {p0[6]}\n")
    return path


def _run(case: dict, intrinsics: str, folder: Path) -> dict:
    argv = ["run", "--dataset", str(case["images"]), "--intrinsics", intrinsics, "--odometry", "none",
            "--ground-truth", str(case["truth"]), "--rerun", "off", "--quiet", "--out", str(folder),
            *case["extra"]]
    t = time.perf_counter()
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        status = graphslam(argv)
    seconds = time.perf_counter() - t
    sys.stderr.write(err.getvalue())
    if status == 2 and intrinsics == "estimate":  # the estimate refused, in one line: a result
        refusal = [ln for ln in err.getvalue().splitlines() if ln.startswith("graphslam: error:")]
        return {"refused": refusal[-1] if refusal else f"status {status}", "seconds": seconds}
    if status != 0:
        raise SystemExit(f"graphslam {' '.join(argv)} ended with status {status}")
    metrics = json.loads((folder / "metrics.json").read_text())
    return {"metrics": metrics, "seconds": seconds}


def measure(case: dict, work: Path) -> dict:
    """Both runs of ``case`` in folders under ``work``; the figures of the module docstring."""
    work = work / case["name"]
    est = _run(case, "estimate", work / "estimate")
    cal = _run(case, str(case["intrinsics"]), work / "calibrated")
    truth = case["calibrated"]
    if "refused" in est:
        return {"name": case["name"], "calibrated": truth, "refused": est["refused"],
                "ate_percent_calibrated": cal["metrics"]["ate_percent_of_path"],
                "seconds_estimated": est["seconds"], "seconds_calibrated": cal["seconds"]}
    camera = est["metrics"]["camera_estimate"]
    return {
        "name": case["name"],
        "calibrated": truth,
        "estimated": {k: camera[k] for k in ("fx_px", "k1", "sigma_f_px", "sigma_k1", "cx_px", "cy_px")},
        "f_off_sigmas": (camera["fx_px"] - truth["f_px"]) / camera["sigma_f_px"],
        "k1_off_sigmas": (camera["k1"] - truth["k1"]) / camera["sigma_k1"],
        "starts": camera["starts"],
        "ate_percent_estimated": est["metrics"]["ate_percent_of_path"],
        "ate_percent_calibrated": cal["metrics"]["ate_percent_of_path"],
        "seconds_estimated": est["seconds"],
        "seconds_calibrated": cal["seconds"],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=entry.output_file, default=HERE / "results" / "self_calibration.json")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:  # the runs' folders: not results
        rows = [measure(case, Path(tmp)) for case in _cases(args.data, Path(tmp), args.quick)]
    for r in rows:
        if "refused" in r:
            print(f"{r['name']}: refused: {r['refused']}; calibrated camera: ATE "
                  f"{r['ate_percent_calibrated']:.2f} % of the path", flush=True)
            continue
        e, c = r["estimated"], r["calibrated"]
        print(
            f"{r['name']}: f {e['fx_px']:.1f} +- {e['sigma_f_px']:.1f} px (calibrated {c['f_px']:.1f}, "
            f"{r['f_off_sigmas']:+.2f} sigma), k1 {e['k1']:.4f} +- {e['sigma_k1']:.4f} (calibrated "
            f"{c['k1']:.4f}, {r['k1_off_sigmas']:+.2f} sigma); ATE {r['ate_percent_estimated']:.2f} % of the "
            f"path (calibrated camera: {r['ate_percent_calibrated']:.2f} %); {r['seconds_estimated']:.0f} s "
            f"(calibrated: {r['seconds_calibrated']:.0f} s)",
            flush=True,
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, {"quick": args.quick, "rows": rows}, indent=1)
    panels = []
    for r in rows:
        if "refused" in r:
            continue
        series = {}
        for s in r["starts"]:
            fs = [s["start_f_px"]] + [x["f_out_px"] for x in s["rounds"]]
            series[f"from {s['start_f_px']:.0f} px"] = (list(range(len(fs))), fs)
        panels.append(
            Panel(
                f"{r['name']}: ATE {r['ate_percent_estimated']:.2f} % of the path "
                f"(calibrated {r['ate_percent_calibrated']:.2f} %)",
                "round (k1 held until f settles, then free)",
                "focal length [px]",
                series,
                targets={f"calibration {r['calibrated']['f_px']:.1f} px": r["calibrated"]["f_px"]},
            )
        )
    save_figure(args.out, "run --intrinsics estimate: the focal length per round from both starts", panels)
    return 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
