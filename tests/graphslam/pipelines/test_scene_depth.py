"""The sequence's nearest depth against the file's ``[mono_ekf] min_depth_m``."""

from __future__ import annotations

from slamcore.config import ConfigFile


def test_the_scene_depth_yields_to_the_file_in_any_toml_form(tmp_path):
    from graphslam.pipelines.spatial import scene_nearest_depth

    class Sequence:
        nearest_depth_m = 2.0

    for text in ("[mono_ekf]\nmin_depth_m = 0.3\n", "[mono_ekf]\n'min_depth_m' = 0.3\n",
                 "mono_ekf = {min_depth_m = 0.3}\n"):
        (tmp_path / "c.toml").write_text(text)
        assert scene_nearest_depth(Sequence(), ConfigFile.read(tmp_path / "c.toml")) is None
    assert scene_nearest_depth(Sequence(), ConfigFile.read(None)) == 2.0
