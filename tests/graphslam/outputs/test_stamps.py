"""Stamps in trajectory.tum and localize.csv: distinct stamps are read back distinct
(6 decimals wrote 300 stamps 0.1 us apart as 31 values, and ``graphslam eval`` refused
the run's own files: "time 0.0 is duplicated"), the common stamps as they were."""

from __future__ import annotations

import numpy as np

from graphslam.cli.main import main
from graphslam.outputs.localize import write_localize_csv
from graphslam.outputs.writers import write_tum_planar
from graphslam.sources.ground_truth import read_trajectory


def _stamps_written(path) -> list[str]:
    return [line.split()[0] for line in path.read_text().splitlines() if not line.startswith("#")]


def test_stamps_a_tenth_of_a_microsecond_apart_are_read_back_and_scored(tmp_path, capsys):
    stamps = np.arange(300) * 1e-7
    poses = np.column_stack([np.arange(300) * 1e-4, np.zeros(300), np.zeros(300)])
    write_tum_planar(tmp_path / "t.tum", stamps, poses)
    read = read_trajectory(tmp_path / "t.tum").stamps_s
    assert np.unique(read).size == 300 and np.allclose(read, stamps, rtol=0, atol=1e-12)
    ev = tmp_path / "ev"
    assert main(["eval", str(tmp_path / "t.tum"), str(tmp_path / "t.tum"), "--no-plot", "--out", str(ev)]) == 0
    capsys.readouterr()


def test_stamps_closer_than_a_nanosecond_are_written_exactly(tmp_path):
    stamps = 1.0 + np.arange(5) * 1e-12
    write_tum_planar(tmp_path / "t.tum", stamps, np.zeros((5, 3)))
    assert np.array_equal(read_trajectory(tmp_path / "t.tum").stamps_s, stamps)


def test_common_stamps_are_written_as_before(tmp_path):
    """KITTI's times (microseconds), MRCLAM's (milliseconds), whole seconds, and a step of
    0.1 s summed in floating point (0.30000000000000004): as 6 decimals wrote them."""
    stamps = np.array([0.0, 0.10364, 0.30000000000000004, 1248272272.841, 2.0, 12.5])
    write_tum_planar(tmp_path / "t.tum", stamps, np.zeros((6, 3)))
    assert _stamps_written(tmp_path / "t.tum") == ["0", "0.103640", "0.300000", "1248272272.841000", "2", "12.500000"]
    write_tum_planar(tmp_path / "ids.tum", np.array([3, 2**62]), np.zeros((2, 3)))
    assert _stamps_written(tmp_path / "ids.tum") == ["3", str(2**62)]


def test_localize_csv_stamps_keep_distinct_stamps_distinct(tmp_path):
    stamps = 5.0 + np.arange(4) * 1e-7
    write_localize_csv(tmp_path / "l.csv", range(4), stamps, ["lost"] * 4, [None] * 4, [None] * 4)
    rows = tmp_path.joinpath("l.csv").read_text().splitlines()[1:]
    assert [r.split(",")[1] for r in rows] == ["5.000000", "5.0000001", "5.0000002", "5.0000003"]
