"""The fifteenth hostile pass (written outputs and help texts): each test reproduces a
finding that was silent or wrong, then checks what the output holds now."""

from __future__ import annotations

from graphslam.cli.main import main


def _pose_times(path, entity: str) -> list[tuple[int, float | None]]:
    """``(step, time in s or None)`` of every row logged at ``entity``."""
    from rerun.chunk import RrdReader

    rows = []
    for chunk in RrdReader(str(path)).stream():
        if chunk.entity_path != entity or chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        steps = batch.column("step").to_pylist()
        times = (batch.column("time").to_pylist() if "time" in batch.schema.names
                 else [None] * batch.num_rows)
        rows += [(s, None if t is None else t.total_seconds()) for s, t in zip(steps, times)]
    return sorted(rows, key=lambda r: r[0])


def test_compare_recording_logs_each_back_ends_poses_at_their_own_time(tmp_path, capsys):
    """compare.rrd: the first back end's poses had no time (one row at its last step), every
    later one's had one time, the first back end's last stamp; run.rrd had the right ones."""
    out = tmp_path / "c"
    assert main(["compare", "--max-steps", "12", "--backends", "isam2", "ekf", "--out", str(out)]) == 0
    capsys.readouterr()
    for entity in ("/world/isam2/pose", "/world/ekf/pose", "/world/ekf/pose_ellipse", "/plots/ekf/pose_sigma_m"):
        rows = _pose_times(out / "compare.rrd", entity)
        assert {s for s, _ in rows} == set(range(12)), entity
        # the synthetic stream's dt is 1 s from 0: step k is at k seconds
        assert all(t is not None and abs(t - s) < 1e-6 for s, t in rows), (entity, rows)
