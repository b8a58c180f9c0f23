"""The README's commands are what CI runs."""

import re

from tests.conftest import ROOT


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)\n```", readme, flags=re.S)
    test_cmd = next(b for b in blocks if "pytest" in b)
    ci = (ROOT / ".ci" / "run").read_text()
    assert test_cmd.strip() in ci.splitlines()


def readme_commands() -> list[str]:
    """The ``graphslam`` lines of the README's bash blocks (the install line is CI's own)."""
    readme = (ROOT / "README.md").read_text()
    return [line.strip() for block in re.findall(r"```bash\n(.*?)\n```", readme, flags=re.S)
            for line in block.splitlines() if line.strip().startswith("graphslam ")]


def test_the_readme_commands_run(tmp_path, shared_data):
    """Each command as a user types it after the install, from a checkout beside
    ``../shared``: exit 0, and the files the README says it writes are there."""
    import shlex
    import subprocess
    import sys

    repo = tmp_path / "repo"
    repo.mkdir()
    (repo / "benchmarks").symlink_to(ROOT / "benchmarks")
    (tmp_path / "shared").symlink_to(shared_data.parent)
    commands = readme_commands()
    assert len(commands) == 3
    for command in commands:
        result = subprocess.run([sys.executable, "-m", "graphslam", *shlex.split(command)[1:]],
                                cwd=repo, capture_output=True, text=True, timeout=900)
        assert result.returncode == 0, f"{command}\n{result.stderr[-2000:]}"
        assert "Traceback" not in result.stderr
    run = repo / "runs" / "kitti07-isam2"
    for name in ("trajectory.tum", "landmarks.csv", "metrics.json", "ground_truth.tum", "run.rrd"):
        assert (run / name).is_file(), name
    assert (repo / "runs" / "eval" / "eval.png").is_file()
    assert (repo / "runs" / "synthetic-compare" / "compare.json").is_file()
