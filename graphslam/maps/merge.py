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

import numpy as np

from graphslam.maps.files import check_camera
from graphslam.maps.spatial_map import SpatialMap
from slamcore.errors import InputError


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


def repeated_session(old: SpatialMap, meta: dict) -> int | None:
    """Index of the session of ``old`` that ran the same frames of the same source as the
    session ``meta`` describes (joining it again adds its keyframes twice), or None."""
    new = _session(meta)
    for i, s in enumerate(old.meta.get("sessions", [_session(old.meta)])):
        if (s.get("source"), s.get("dataset"), s.get("frames")) == (
            new["source"],
            new["dataset"],
            new["frames"],
        ):
            return i
    return None


def _session(meta: dict) -> dict:
    """What a session entry of ``meta["sessions"]`` keeps of a map's description."""
    return {
        k: meta.get(k)
        for k in ("dataset", "source", "frames", "n_frames", "backend", "frontend", "densified_landmarks")
    }
