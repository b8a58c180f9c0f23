"""Same outputs before and after a refactor: SHA-256 of the files a set of commands write.

Runs the default ``graphslam run`` (iSAM2, the EKF and FastSLAM, known and unknown
association), ``--dataset victoria-park``, the synthetic image sequence on both
visual back ends and from the camera alone, the monocular EKF on KITTI 07 without
odometry, and ``graphslam loops`` on KITTI 07,
each with ``--rerun off`` into a temporary folder, and compares the trajectory,
landmark and loop files byte for byte with ``digests.json`` (recorded by
``--record``, or ``--record --only CASE ...`` for some cases, the others kept; the file
says which commit and machine each case's digests came from).

Floating-point results are only bit-identical on the same BLAS and CPU
features, so this is a script to run on the team's machine around a
refactor, not a CI test.

    python benchmarks/check_digests.py            # compare (about 2 minutes)
    python benchmarks/check_digests.py --record   # store new digests
"""

from __future__ import annotations

import quiet_start  # noqa: F401  (first: a signal while the imports load is one line)

import argparse
import hashlib
import json
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data"
DIGESTS = HERE / "digests.json"

#: name -> (arguments after ``graphslam``, files whose bytes must not change)
CASES: dict[str, tuple[list[str], list[str]]] = {
    "synthetic-isam2": (["run", "--rerun", "off", "--quiet"],
                        ["trajectory.tum", "landmarks.csv"]),
    "victoria-park-isam2": (["run", "--dataset", "victoria-park", "--rerun", "off", "--quiet"],
                            ["trajectory.tum", "landmarks.csv"]),
    "synthetic-images-isam2": (["run", "--dataset", "synthetic-images", "--backend", "isam2",
                                "--rerun", "off", "--quiet"], ["trajectory.tum", "landmarks.csv"]),
    "synthetic-images-ekf": (["run", "--dataset", "synthetic-images", "--backend", "ekf",
                              "--rerun", "off", "--quiet"], ["trajectory.tum", "landmarks.csv"]),
    # the filters' 2-D runs (known and unknown association), the camera alone and the
    # monocular EKF's anchored parametrisation: every back end's code paths, so that a
    # refactor of any one of them is checked
    "synthetic-ekf": (["run", "--backend", "ekf", "--rerun", "off", "--quiet"],
                      ["trajectory.tum", "landmarks.csv"]),
    "synthetic-ekf-unknown": (["run", "--backend", "ekf", "--config",
                               str(HERE / "digests_unknown.toml"), "--rerun", "off", "--quiet"],
                              ["trajectory.tum", "landmarks.csv"]),
    "synthetic-fastslam1": (["run", "--backend", "fastslam1", "--rerun", "off", "--quiet"],
                            ["trajectory.tum", "landmarks.csv"]),
    "synthetic-fastslam2-unknown": (["run", "--backend", "fastslam2", "--config",
                                     str(HERE / "digests_unknown.toml"), "--rerun", "off",
                                     "--quiet"], ["trajectory.tum", "landmarks.csv"]),
    "synthetic-images-isam2-alone": (["run", "--dataset", "synthetic-images", "--odometry",
                                      "none", "--frames", "0:120", "--rerun", "off", "--quiet"],
                                     ["trajectory.tum", "landmarks.csv"]),
    "kitti07-ekf-alone": (["run", "--dataset", str(SHARED / "kitti07"), "--backend", "ekf",
                           "--odometry", "none", "--config",
                           str(HERE / "kitti07_mono.toml"), "--rerun", "off", "--quiet"],
                          ["trajectory.tum", "landmarks.csv"]),
    "kitti07-loops": (["loops", str(SHARED / "kitti07" / "image_0"), "--quiet"],
                      ["loops.csv", "loops.jsonl"]),
}


def graphslam_exe() -> str:
    """The console script of the interpreter running this file."""
    local = Path(sys.executable).parent / "graphslam"
    return str(local) if local.exists() else (shutil.which("graphslam") or "graphslam")


def run_case(name: str, workdir: Path) -> dict[str, str]:
    args, files = CASES[name]
    out = workdir / name
    if args[0] == "loops":
        cmd = [graphslam_exe(), *args, "--out", str(out / "loops.csv"),
               "--log", str(out / "loops.jsonl")]
    else:
        cmd = [graphslam_exe(), *args, "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{name}: exit {proc.returncode}\n{proc.stderr[-2000:]}")
    return {f: hashlib.sha256((out / f).read_bytes()).hexdigest() for f in files}


def git_head() -> str:
    """HEAD's hash, ``+changes`` when the library's files differ from it (the digests are
    then of the change about to be committed on it)."""
    proc = subprocess.run(["git", "rev-parse", "HEAD"], cwd=HERE, capture_output=True, text=True)
    dirty = subprocess.run(["git", "diff", "--quiet", "HEAD", "--", "graphslam", "filters", "slamcore",
                            "frontend", "loopclosure", "datasets"], cwd=HERE.parent).returncode != 0
    return (proc.stdout.strip() or "unknown") + (" +changes" if dirty else "")


def origin_of(stored: dict, name: str) -> dict:
    """Commit, machine and Python a case's digests were recorded with (a file from before
    per-case origins names one for all)."""
    return stored.get("recorded", {}).get(name) or {k: stored.get(k, "?") for k in ("commit", "machine", "python")}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--record", action="store_true", help="store the digests instead of comparing")
    ap.add_argument("--only", nargs="+", choices=sorted(CASES), help="run only these cases")
    args = ap.parse_args()
    names = args.only or list(CASES)
    with tempfile.TemporaryDirectory() as tmp:
        got = {}
        for name in names:
            print(f"running {name} ...", file=sys.stderr, flush=True)
            got[name] = run_case(name, Path(tmp))
    if args.record:
        # --only records those cases and keeps every other case's digests and origin
        old = json.loads(DIGESTS.read_text()) if args.only and DIGESTS.is_file() else {"digests": {}}
        origin = {"commit": git_head(), "machine": f"{platform.machine()} {platform.processor()}",
                  "python": platform.python_version()}
        recorded = {n: origin_of(old, n) for n in old["digests"]}
        recorded.update({n: origin for n in got})
        DIGESTS.write_text(json.dumps({"digests": {**old["digests"], **got}, "recorded": recorded},
                                      indent=2) + "\n")
        print(f"recorded {', '.join(got)} in {DIGESTS}")
        return 0
    stored = json.loads(DIGESTS.read_text())
    bad = 0
    for name in names:
        for f, digest in got[name].items():
            same = stored["digests"][name][f] == digest
            bad += not same
            print(f"{'same' if same else 'DIFFERENT':9s} {name}/{f} "
                  f"(recorded at {origin_of(stored, name)['commit'][:10]})")
    print(f"{'all identical' if not bad else f'{bad} file(s) differ'}")
    return 1 if bad else 0


if __name__ == "__main__":
    import entry  # a module, not its run(): some scripts have a run() of their own

    raise SystemExit(entry.run(main))
