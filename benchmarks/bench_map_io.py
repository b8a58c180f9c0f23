"""Saving and loading a 10 000-keyframe map (issue 18: each under 2 s), beside a baseline.

The map is synthetic and of realistic proportions: 10 000 keyframes, 100 000
landmarks (with 11x11 float32 patches and 3x3 covariances), 60 observations
per keyframe (600 000 pixels with their ORB descriptors), 500 bag-of-words
entries per keyframe (5 000 000), a 1 000-word vocabulary. Baseline, in the
same process: ``np.savez`` / ``np.load`` of the same arrays (numpy's own
writer, pickle off), so the ratio shows what the format's checks (SHA-256,
shape checks, the byte-reproducible zip) cost. Ours and the baseline are
alternated ``--repeat`` times by ``benchmarks/timing.py`` (median, not best-of).

JSON (default ``benchmarks/results/map_io.json``) and its PNG beside it.

    python benchmarks/bench_map_io.py [--keyframes N] [--repeat R] [--quick] [--out FILE.json]
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from graphslam.maps.files import load_map, save_map  # noqa: E402
from graphslam.maps.spatial_map import SpatialMap  # noqa: E402
import timing  # noqa: E402
from loopclosure.vocabulary import FlatVocabulary  # noqa: E402
import entry  # noqa: E402  (beside this script: --quick sizes, argparse types)

TARGET_S = 2.0


def big_map(n_kf: int, seed: int = 0, words: int = 1000, bow_kf: int = 500) -> SpatialMap:
    """The synthetic map; ``words`` and ``bow_kf`` (BoW entries per keyframe) shrink for ``--quick``."""
    rng = np.random.default_rng(seed)
    n_lm, per_kf = 10 * n_kf, 60
    vocab = FlatVocabulary(n_words=words, seed=0).fit(
        [rng.integers(0, 256, (2000, 32), dtype=np.uint8) for _ in range(3)])
    wTc = np.tile(np.eye(4), (n_kf, 1, 1))
    wTc[:, :3, 3] = rng.normal(size=(n_kf, 3))
    n_obs = per_kf * n_kf
    bow_words = np.sort(np.stack([rng.choice(words, bow_kf, replace=False) for _ in range(n_kf)]),
                        axis=1).reshape(-1)
    weights = rng.random((n_kf, bow_kf))
    weights /= weights.sum(axis=1, keepdims=True)
    return SpatialMap(
        K=np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]), image_size=(640, 480),
        keyframe_ids=np.arange(n_kf, dtype=np.int64), keyframe_wTc=wTc,
        keyframe_cov=np.tile(np.eye(6) * 1e-4, (n_kf, 1, 1)),
        landmark_ids=np.arange(n_lm, dtype=np.int64), landmark_w=rng.normal(size=(n_lm, 3)),
        landmark_cov=np.tile(np.eye(3) * 1e-3, (n_lm, 1, 1)),
        landmark_desc=rng.integers(0, 256, (n_lm, 32), dtype=np.uint8),
        landmark_patch=rng.random((n_lm, 11, 11), dtype=np.float32),
        obs_keyframe=np.repeat(np.arange(n_kf, dtype=np.int64), per_kf),
        obs_landmark=rng.integers(0, n_lm, n_obs).astype(np.int64),
        obs_uv=rng.uniform(0, 480, (n_obs, 2)),
        obs_desc=rng.integers(0, 256, (n_obs, 32), dtype=np.uint8),
        bow_indptr=np.arange(0, n_kf * bow_kf + 1, bow_kf, dtype=np.int64),
        bow_words=bow_words.astype(np.int64), bow_weights=weights.reshape(-1),
        vocabulary=vocab, meta={"benchmark": "bench_map_io"})


def plot(out: dict, repeat: int, path: Path) -> Path:
    """Save and load times of the map format beside np.savez / np.load, with the 2 s target."""
    from plotting import Panel, save_figure  # beside this script

    ops = ["save", "load"]
    return save_figure(path, f"Map files: {out['keyframes']} keyframes, {out['size_mb']} MB, median of "
                             f"{repeat}", [
        Panel(f"save x{out['save_ratio']:.2f}, load x{out['load_ratio']:.2f} the baseline", "operation",
              "wall time [s]", {"graphslam.maps (save_map / load_map)": (ops, [out["save_s"], out["load_s"]]),
                                "baseline np.savez / np.load": (ops, [out["baseline_savez_s"],
                                                                     out["baseline_load_s"]])},
              kind="bar", logy=True, targets={f"target {out['target_s']:g} s": out["target_s"]})],
        ncols=1)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keyframes", type=entry.count, default=10_000)
    ap.add_argument("--repeat", type=entry.count, default=3)
    ap.add_argument("--quick", action="store_true", help="100 keyframes, 100 words, 1 repeat")
    ap.add_argument("--out", type=entry.output_file, default=Path(__file__).resolve().parent / "results" / "map_io.json",
                    help="JSON to write (and its PNG beside it)")
    args = ap.parse_args(argv)
    if args.quick:
        entry.quick_sizes(ap, argv, args, keyframes=100, repeat=1)
    smap = big_map(args.keyframes, **({"words": 100, "bow_kf": 50} if args.quick else {}))
    arrays = {n: getattr(smap, n) for n in ("keyframe_wTc", "keyframe_cov", "landmark_w",
                                             "landmark_cov", "landmark_desc", "landmark_patch",
                                             "obs_keyframe", "obs_landmark", "obs_uv", "obs_desc",
                                             "bow_indptr", "bow_words", "bow_weights")}
    with tempfile.TemporaryDirectory() as tmp:
        folder, plain = Path(tmp) / "map", Path(tmp) / "plain.npz"
        def base_load():
            with np.load(plain, allow_pickle=False) as z:
                return {n: z[n] for n in z.files}
        t = timing.alternate({"save": lambda: save_map(smap, folder),
                              "savez": lambda: np.savez(plain, **arrays)}, args.repeat, warmup=0)
        t.update(timing.alternate({"load": lambda: load_map(folder), "np.load": base_load},
                                  args.repeat, warmup=0))
        save_s, base_save_s, load_s, base_load_s = (
            t[k].median_s for k in ("save", "savez", "load", "np.load"))
        size_mb = sum(p.stat().st_size for p in folder.iterdir()) / 1e6
    out = {"keyframes": args.keyframes, "counts": smap.counts(), "size_mb": round(size_mb, 1),
           "save_s": save_s, "load_s": load_s, "baseline_savez_s": base_save_s,
           "baseline_load_s": base_load_s, "save_ratio": save_s / base_save_s,
           "load_ratio": load_s / base_load_s, "target_s": TARGET_S,
           "pass": bool(save_s < TARGET_S and load_s < TARGET_S)}
    cmd = "python benchmarks/bench_map_io.py"
    out["summaries"] = [timing.summary(
        f"map {op} ({args.keyframes} keyframes)", ours, base, target=None, target_abs_s=TARGET_S,
        floor=f"np.{name} of the same arrays", command=cmd)
        for op, ours, base, name in (("save", save_s, base_save_s, "savez"),
                                     ("load", load_s, base_load_s, "load"))]
    print(json.dumps(out, indent=2))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    entry.write_json(args.out, out, indent=2, trailing_newline=True)
    plot(out, args.repeat, args.out)
    return 0 if out["pass"] else 1


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
