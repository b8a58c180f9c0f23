"""A 100 000-pose chain (issue 34): gtsam's recursive elimination overflowed the
main thread's stack in batch LM and killed the interpreter (SIGSEGV); the deep
gtsam calls now run on a deep-stack thread (``graphslam.backends.deep_stack``).
Run in a subprocess, so that a crash fails this test instead of pytest."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from graphslam.backends import deep_stack

#: Poses of the chain: the issue's size, at which the 8 MiB main stack overflowed.
CHAIN_POSES = 100_000


def test_deep_stack_call_returns_and_raises_as_a_direct_call():
    assert deep_stack.call(sum, [1, 2, 3]) == 6
    with pytest.raises(ZeroDivisionError):
        deep_stack.call(lambda: 1 / 0)


@pytest.mark.slow
def test_batch_on_a_100k_pose_chain_ends_in_a_valid_run(tmp_path):
    path = tmp_path / "chain.g2o"
    path.write_text("".join(f"EDGE_SE2 {k - 1} {k} 1 0 0.001 100 0 0 100 0 1000\n"
                            for k in range(1, CHAIN_POSES)))
    done = subprocess.run([sys.executable, "-m", "graphslam.cli.main", "run", "--dataset",
                           str(path), "--backend", "batch", "--out", str(tmp_path / "o"),
                           "--rerun", "off", "--quiet"], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert metrics["poses"] == CHAIN_POSES and metrics["final_cost"] < 1e-6
