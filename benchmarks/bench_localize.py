"""Issue 18's "done means", measured: maps saved, loaded and localised against.

1. Synthetic room (1.5 laps, 300 frames): ``graphslam run --frames 0:200
   --save-map``, then ``graphslam localize --frames 200:300`` from an unknown
   start pose; localised share, ATE (the map's frame, no alignment), largest
   error of a placed frame. Baseline, same process: the full SLAM run over all
   300 frames (its SE(3)-aligned ATE, and its unaligned error over frames
   200-299, the same frames).
2. KITTI 07 frames 0-159: map the even frames (``--frames 0:160:2``,
   ``benchmarks/kitti07_visual.toml``, derived odometry), localise the odd
   ones (``1:160:2``) from an unknown start; localised share and median error.
   The same odd frames played backwards (``159::-2``), whatever they give.
3. Tracking loss: frames 200-299 of the room with 10 black frames in the
   middle (240-249): frames until placed again after them.
4. Round trip: save, load, save gives identical files.

JSON (default ``benchmarks/results/localize.json``) and its PNG beside it.
``--quick``: a 90-frame room (map 0-59, localise 60-89, frames 70-72 black),
KITTI skipped.

    python benchmarks/bench_localize.py [--out FILE.json] [--skip-kitti] [--quick]
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import json
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from graphslam.cli.main import main as graphslam  # noqa: E402
import entry  # noqa: E402  (beside this script: its argparse types)

KITTI = ROOT.parent / "shared" / "data" / "kitti07"
BLACK = range(40, 50)  # frames 240-249 of the localised range 200:300


@dataclass(frozen=True)
class Plan:
    """Frames of the room runs: map ``0:split``, localise ``split:n_frames`` (blacked out: ``black``,
    relative to ``split``); ``config`` sets ``[synthetic_images] n_frames`` when not the default 300."""

    n_frames: int = 300
    split: int = 200
    black: range = BLACK
    config: Path | None = None

    def config_args(self) -> list:
        return [] if self.config is None else ["--config", self.config]


def quick_plan(tmp: Path) -> Plan:
    """A 90-frame room (same 1.5 laps), for a smoke run."""
    config = tmp / "quick.toml"
    config.write_text("[synthetic_images]\nn_frames = 90\n")
    return Plan(90, 60, range(10, 13), config)


def cli(*argv) -> None:
    rc = graphslam([*map(str, argv), "--quiet"])
    if rc != 0:
        raise SystemExit(f"graphslam {' '.join(map(str, argv))} exited with {rc}")


def metrics(folder: Path) -> dict:
    return json.loads((folder / "metrics.json").read_text())


def tum_xyz(path: Path) -> np.ndarray:
    return np.loadtxt(path)[:, 1:4]


def room(tmp: Path, plan: Plan = Plan()) -> dict:
    a, n, cfg = plan.split, plan.n_frames, plan.config_args()
    cli("run", "--dataset", "synthetic-images", "--frames", f"0:{a}", "--save-map", tmp / "map",
        "--out", tmp / "map_run", "--rerun", "off", *cfg)
    cli("localize", "--map", tmp / "map", "--dataset", "synthetic-images", "--frames", f"{a}:{n}",
        "--out", tmp / "loc", *cfg)
    cli("run", "--dataset", "synthetic-images", "--out", tmp / "full", "--rerun", "off", *cfg)
    loc, full = metrics(tmp / "loc"), metrics(tmp / "full")
    err = np.linalg.norm(tum_xyz(tmp / "full/trajectory.tum") - tum_xyz(tmp / "full/ground_truth.tum"),
                         axis=1)[a:]
    return {"localised_fraction": loc["localised_fraction"], "tracked": loc["tracked"],
            "relocalisations": loc["relocalisations"], "lost_frames": loc["lost_frames"],
            "ate_rmse_m": loc["ate_rmse_m"], "error_max_m": loc["error_max_m"],
            "frames_over_0_5m": loc["frames_over_0_5m"],
            "map_run_ate_rmse_m_se3": metrics(tmp / "map_run")["ate_rmse_m"],
            "full_slam_ate_rmse_m_se3": full["ate_rmse_m"],
            f"full_slam_error_rmse_m_frames_{a}_{n - 1}_unaligned": float(np.sqrt(np.mean(err**2))),
            "pass": bool(loc["localised_fraction"] >= 0.95 and loc["ate_rmse_m"] <= full["ate_rmse_m"]
                         and loc["frames_over_0_5m"] == 0)}


def kitti(tmp: Path) -> dict:
    # derived odometry: the map must hold metric lengths to localise against in metres
    cli("run", "--dataset", KITTI, "--frames", "0:160:2", "--odometry", "derived", "--config",
        ROOT / "benchmarks/kitti07_visual.toml", "--save-map", tmp / "kmap", "--out",
        tmp / "kmap_run", "--rerun", "off")
    out = {"map_run_ate_rmse_m_se3": metrics(tmp / "kmap_run")["ate_rmse_m"]}
    for name, frames in (("forward", "1:160:2"), ("backwards", "159::-2")):
        cli("localize", "--map", tmp / "kmap", "--dataset", KITTI, "--frames", frames,
            "--out", tmp / name, "--rerun", "off")
        m = metrics(tmp / name)
        out[name] = {k: m.get(k) for k in ("frames", "localised_fraction", "relocalisations",
                                           "lost_frames", "ate_rmse_m", "error_median_m",
                                           "error_max_m")}
    f = out["forward"]
    out["pass"] = bool(f["localised_fraction"] >= 0.9 and f["error_median_m"] < 0.3)
    return out


def blackout(tmp: Path, plan: Plan = Plan()) -> dict:
    from graphslam import registry
    from graphslam.maps.files import load_map
    from graphslam.pipelines import localize_run
    from graphslam.pipelines.common import whole
    from graphslam.pipelines.localize import make_localizer
    from graphslam.sources.spatial.frames import black_out, parse_frames, select_frames

    config = registry.read_config(plan.config)
    sel = select_frames(registry.load_image_sequence("synthetic-images", config=config),
                        parse_frames(f"{plan.split}:{plan.n_frames}"))
    black = plan.black
    seq = black_out(sel, black)
    res = whole(localize_run.run(seq, make_localizer(load_map(tmp / "map"), seq.K, config)))
    status = [p.status for p in res.placements]
    after = status[black[-1] + 1:]
    recover = next((i + 1 for i, s in enumerate(after) if s != "lost"), None)
    err = localize_run.errors_m(res)
    return {"black_frames": f"{plan.split + black[0]}-{plan.split + black[-1]}",
            "lost_in_blackout": sum(status[i] == "lost" for i in black),
            "frames_to_recover": recover, "status_after": after[:3],
            "error_max_m": float(np.nanmax(err)), "pass": recover is not None and recover <= 3}


def round_trip(tmp: Path) -> dict:
    from graphslam.maps.files import load_map, save_map

    save_map(load_map(tmp / "map"), tmp / "again")
    same = {n: (tmp / "map" / n).read_bytes() == (tmp / "again" / n).read_bytes()
            for n in ("map.json", "map.npz", "vocabulary.npz")}
    return {"identical": same, "pass": all(same.values())}


def plot(out: dict, plan: Plan, path: Path) -> Path:
    """Localised share against its target, and position errors beside the full SLAM run's."""
    from plotting import Panel, save_figure  # beside this script

    r, a, n = out["synthetic_room"], plan.split, plan.n_frames
    runs = {f"room {a}-{n - 1}": r["localised_fraction"]}
    errors = {f"localised {a}-{n - 1}: ATE (map frame)": r["ate_rmse_m"],
              f"localised {a}-{n - 1}: largest": r["error_max_m"],
              "full SLAM: ATE (SE(3)-aligned)": r["full_slam_ate_rmse_m_se3"],
              f"full SLAM {a}-{n - 1}: unaligned": r[f"full_slam_error_rmse_m_frames_{a}_{n - 1}_unaligned"]}
    for name in ("forward", "backwards"):
        if name in out.get("kitti07", {}):
            runs[f"KITTI 07 odd frames, {name}"] = out["kitti07"][name]["localised_fraction"]
            errors[f"KITTI 07 {name}: median"] = out["kitti07"][name]["error_median_m"]
    b = out["blackout"]
    return save_figure(path, f"Localisation against saved maps; after black frames {b['black_frames']}: "
                             f"placed again in {b['frames_to_recover']} frames", [
        Panel("frames localised", "run", "localised [%]",
              {"localised": (list(runs), [100 * v for v in runs.values()])}, kind="bar", ylim=(0, 105),
              targets={"room target 95 %": 95.0, "KITTI target 90 %": 90.0}),
        Panel("position errors", "measure", "error [m]", {"error": (list(errors), list(errors.values()))},
              kind="bar")])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=entry.output_file, default=ROOT / "benchmarks" / "results" / "localize.json",
                    help="JSON to write (and its PNG beside it)")
    ap.add_argument("--skip-kitti", action="store_true")
    ap.add_argument("--quick", action="store_true", help="a 90-frame room, no KITTI (see the docstring)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        plan = quick_plan(tmp) if args.quick else Plan()
        out = {"synthetic_room": room(tmp, plan), "blackout": blackout(tmp, plan),
               "round_trip": round_trip(tmp)}
        if not (args.skip_kitti or args.quick) and KITTI.is_dir():
            out["kitti07"] = kitti(tmp)
    print(json.dumps(out, indent=2))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, out, indent=2, trailing_newline=True)
    plot(out, plan, args.out)
    return 0 if all(v["pass"] for v in out.values()) else 1


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
