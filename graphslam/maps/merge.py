"""Join two sessions' maps into one (``graphslam run --map OLD --save-map NEW``).

The second session was anchored in the first map's frame by relocalisation,
so both are in one world frame and the join is a concatenation: keyframes
after the old ones, landmarks after the old ones (the new session's track ids
shifted past the old ids so that no two landmarks share one; densified
landmarks keep negative ids, shifted below the old ones), observation indices
shifted accordingly, BoW rows appended. Both maps must share the camera and
the vocabulary (the new session's vectors are computed with the old map's
vocabulary). Nothing is re-optimised: the sessions are tied by the anchor,
not by a joint adjustment.
"""

from __future__ import annotations

import os

import numpy as np

from graphslam.maps.files import check_camera
from graphslam.maps.spatial_map import SpatialMap
from slamcore.errors import ConfigError, InputError


def merge_maps(old: SpatialMap, new: SpatialMap) -> SpatialMap:
    """``old`` followed by ``new`` (module docstring); ``meta["sessions"]`` lists both."""
    if old.vocabulary is not new.vocabulary:
        raise InputError("the two sessions' maps were built with different vocabularies", "--map")
    check_camera(old, new.K, new.image_size, "--map", new.meta.get("distortion"))
    ids = new.landmark_ids.copy()
    pos = ids >= 0
    ids[pos] += int(max(old.landmark_ids.max(initial=-1), -1)) + 1
    ids[~pos] += int(min(old.landmark_ids.min(initial=0), 0))
    cat = np.concatenate
    sessions = list(old.meta.get("sessions", [_session(old.meta)])) + [_session(new.meta)]
    return SpatialMap(
        K=old.K,
        image_size=old.image_size,
        keyframe_ids=cat([old.keyframe_ids, new.keyframe_ids]),
        keyframe_wTc=cat([old.keyframe_wTc, new.keyframe_wTc]),
        keyframe_cov=cat([old.keyframe_cov, new.keyframe_cov]),
        landmark_ids=cat([old.landmark_ids, ids]),
        landmark_w=cat([old.landmark_w, new.landmark_w]),
        landmark_cov=cat([old.landmark_cov, new.landmark_cov]),
        landmark_desc=cat([old.landmark_desc, new.landmark_desc]),
        landmark_patch=cat([old.landmark_patch, new.landmark_patch]),
        obs_keyframe=cat([old.obs_keyframe, new.obs_keyframe + old.n_keyframes]),
        obs_landmark=cat([old.obs_landmark, new.obs_landmark + old.n_landmarks]),
        obs_uv=cat([old.obs_uv, new.obs_uv]),
        obs_desc=cat([old.obs_desc, new.obs_desc]),
        bow_indptr=cat([old.bow_indptr, new.bow_indptr[1:] + old.bow_indptr[-1]]),
        bow_words=cat([old.bow_words, new.bow_words]),
        bow_weights=cat([old.bow_weights, new.bow_weights]),
        vocabulary=old.vocabulary,
        vocabulary_bytes=old.vocabulary_bytes,
        # the joined map's frames are its sessions' (a joined map said the last one's only,
        # and localize reported it as what the map was built from)
        meta={
            **new.meta,
            "sessions": sessions,
            "frames": " + ".join(str(s.get("frames") or "all") for s in sessions),
            "n_frames": sum(int(s.get("n_frames") or 0) for s in sessions),
        },
    )


def frame_range(indices) -> list[int] | None:
    """``[first, last, step]`` of the source frame indices a session ran (``--frames``
    picks an arithmetic run of them), None when it ran none: one spelling for
    ``0:40``, ``:40`` and ``0:40:1``."""
    idx = np.asarray(indices, dtype=np.int64)
    if len(idx) == 0:
        return None
    step = int(idx[1] - idx[0]) if len(idx) > 1 else 1
    return [int(idx[0]), int(idx[-1]), step]


def _ran(session: dict, n_source: int | None) -> list[int] | None:
    """A session's :func:`frame_range`: as recorded, else (a map saved before it was)
    from its ``--frames`` text and frame count, on a source of ``n_source`` frames."""
    if session.get("frame_range") is not None:
        return [int(v) for v in session["frame_range"]]
    if n_source is None:
        return None
    from graphslam.sources.spatial.frames import frame_indices, parse_frames

    try:
        text = session.get("frames")
        idx = frame_indices(parse_frames(text) if text else slice(None), n_source)
    except (ConfigError, ValueError, TypeError):  # not a range this source has
        return None
    n = session.get("n_frames")
    return frame_range(idx[: int(n)] if isinstance(n, int) and n > 0 else idx)


def _where(session: dict) -> str | None:
    """A session's source resolved (absolute, links followed): an old map's path as
    typed is read from here, the best that can be done with it."""
    path = session.get("source_path") or session.get("source")
    return None if path is None else os.path.realpath(str(path))


def repeated_session(old: SpatialMap, meta: dict, n_source: int | None = None) -> int | None:
    """Index of the session of ``old`` that ran the same frames of the same source as the
    session ``meta`` describes (joining it again adds its keyframes twice), or None. The
    source is compared resolved and the frames as the indices run (:func:`frame_range`;
    ``n_source``: the source's frame count, to read an old map's ``--frames`` text): a
    relative path, a linked folder, ``0:40:1`` or ``:40`` hid a repeat before (fifteenth
    hostile pass)."""
    new = _session(meta)
    mine = (_where(new), new["dataset"] if _where(new) is None else None, _ran(new, n_source))
    for i, s in enumerate(old.meta.get("sessions", [_session(old.meta)])):
        if (
            mine[2] is not None
            and (_where(s), s.get("dataset") if _where(s) is None else None, _ran(s, n_source)) == mine
        ):
            return i
    return None


def _session(meta: dict) -> dict:
    """What a session entry of ``meta["sessions"]`` keeps of a map's description."""
    return {
        k: meta.get(k)
        for k in (
            "dataset",
            "source",
            "source_path",
            "frames",
            "frame_range",
            "n_frames",
            "backend",
            "frontend",
            "densified_landmarks",
        )
    }
