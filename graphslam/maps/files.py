"""The map folder: ``map.json`` + ``map.npz`` (+ ``vocabulary.npz``), plain JSON and numpy.

Two kinds share the format and its checks: ``"spatial"`` (a visual map of an
image-sequence run, :class:`~graphslam.maps.spatial_map.SpatialMap`) and
``"planar"`` (a 2-D landmark map, :class:`~graphslam.maps.planar_map.PlanarMap`).

``map.json`` (self-describing; written last, so a folder whose writing was cut
short has none and is refused as incomplete)::

    {"format": "graphslam-map", "version": 1, "kind": "spatial" | "planar",
     "counts": {"keyframes": K, "landmarks": L, "observations": O, ...},
     "arrays": {"file": "map.npz", "sha256": "..."},
     "meta": {...: dataset, frames or steps, back end, the configuration that built it},
     spatial only:
     "camera": {"K": [[...]], "image_size": [W, H]},
     "vocabulary": {"file": "vocabulary.npz", "sha256": "...", "kind": ..., "words": N}}

A version-1 map without ``kind`` is spatial (3-D maps were written before 2-D ones).

``map.npz``: the arrays of :data:`graphslam.maps.spatial_map.ARRAYS` plus
``landmark_patch`` (spatial) or of :data:`graphslam.maps.planar_map.ARRAYS`
(planar), stored uncompressed (a 10 000-keyframe map is written and
read in well under a second) in a zip whose entries carry a fixed date, so
that saving the same map twice gives the same bytes. Read with
``allow_pickle=False``. ``vocabulary.npz`` is the vocabulary's own file format
(:mod:`loopclosure.vocabulary_file`); a loaded map keeps its bytes and writes
them back verbatim.

Refused with one line (:class:`~slamcore.errors.InputError` naming the file):
a missing file, JSON or zip damage, a file whose SHA-256 is not the one
``map.json`` recorded (damaged, truncated or swapped), another format, a
newer version, a map of the other kind (a 2-D map given to an image-sequence
run or the reverse), arrays that disagree with the counts; and, by
:func:`check_camera`, a map built with another camera.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import zipfile
from pathlib import Path

import numpy as np

from graphslam.maps.planar_map import ARRAYS as PLANAR_ARRAYS
from graphslam.maps.planar_map import PlanarMap
from graphslam.maps.spatial_map import ARRAYS, SpatialMap
from slamcore.errors import ConfigError, InputError, quote
from slamcore.files import inside_folder, replacing_all
from slamcore.npz import check_npz_sizes

FORMAT = "graphslam-map"
FORMAT_VERSION = 1
MAP_JSON, MAP_NPZ, VOCAB_NPZ = "map.json", "map.npz", "vocabulary.npz"
#: Largest move of any pixel of the image between two cameras that are the same one,
#: pixels: a hundredth of the keypoints' 1 px sigma. The same intrinsics written to 3
#: decimals (0.0005 px) were refused at 1e-6 on the matrices; another camera moves
#: pixels by whole pixels.
CAMERA_TOL_PX = 0.01
#: Zip entry date of every array (the earliest a zip can hold): same map, same bytes.
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)
_NAMES = tuple(ARRAYS) + ("landmark_patch",)
SPATIAL, PLANAR = "spatial", "planar"
#: What each kind is called in a refusal, and the tables its map.json must hold.
_KIND_TEXT = {SPATIAL: "3-D map of an image sequence", PLANAR: "2-D landmark map"}
_TABLES = {SPATIAL: ("camera", "counts", "arrays", "vocabulary"), PLANAR: ("counts", "arrays")}


def save_map(smap: SpatialMap, folder) -> dict[str, Path]:
    """Write ``smap`` into ``folder`` (created); returns the three paths. The files
    replace an earlier map's only once all are written (:func:`replacing_all`)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    smap.check(folder)
    paths = {"arrays": folder / MAP_NPZ, "vocabulary": folder / VOCAB_NPZ, "json": folder / MAP_JSON}
    with replacing_all(list(paths.values())) as (npz_tmp, vocab_tmp, json_tmp):
        vocab = smap.vocabulary_bytes
        if vocab is None:
            smap.vocabulary.save(vocab_tmp)
            vocab = vocab_tmp.read_bytes()
        else:
            vocab_tmp.write_bytes(vocab)
        doc = {
            "camera": {
                "K": np.asarray(smap.K, float).tolist(),
                "image_size": [int(v) for v in smap.image_size],
            },
            "vocabulary": {
                "file": VOCAB_NPZ,
                "sha256": hashlib.sha256(vocab).hexdigest(),
                "kind": type(smap.vocabulary).__name__,
                "words": int(smap.vocabulary.n_words_),
            },
        }
        _write_arrays_and_json(
            npz_tmp,
            json_tmp,
            SPATIAL,
            {name: getattr(smap, name) for name in _NAMES},
            smap.counts(),
            smap.meta,
            doc,
        )
    smap.vocabulary_bytes = vocab
    return paths


def save_planar_map(pmap: PlanarMap, folder) -> dict[str, Path]:
    """Write the 2-D map ``pmap`` into ``folder`` (created); returns the two paths. The
    files replace an earlier map's only once both are written."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    pmap.check(folder)
    paths = {"arrays": folder / MAP_NPZ, "json": folder / MAP_JSON}
    with replacing_all(list(paths.values())) as (npz_tmp, json_tmp):
        _write_arrays_and_json(npz_tmp, json_tmp, PLANAR, pmap.arrays(), pmap.counts(), pmap.meta, {})
    # a 3-D map's vocabulary saved here before is no part of this map
    (folder / VOCAB_NPZ).unlink(missing_ok=True)
    return paths


def _write_arrays_and_json(
    npz_path: Path,
    json_path: Path,
    kind: str,
    arrays: dict[str, np.ndarray],
    counts: dict,
    meta: dict,
    extra: dict,
) -> None:
    """``map.npz`` of ``arrays`` and ``map.json`` (its presence means complete)."""
    blob = _npz_bytes(arrays)
    _write_synced(npz_path, blob)
    doc = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "kind": kind,
        "counts": counts,
        "arrays": {"file": MAP_NPZ, "sha256": hashlib.sha256(blob).hexdigest()},
        "meta": meta,
        **extra,
    }
    _write_synced(json_path, (json.dumps(doc, indent=1, sort_keys=True) + "\n").encode("utf-8"))


def _write_synced(path: Path, data: bytes) -> None:
    """``data`` to ``path``, on the disk before the rename that makes it the map's
    (a crash after the rename must not leave an empty file under the map's name)."""
    with open(path, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def _npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """An uncompressed .npz of ``arrays`` with fixed entry dates (byte-reproducible)."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name in sorted(arrays):
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.ascontiguousarray(arrays[name]), allow_pickle=False)
            info = zipfile.ZipInfo(name + ".npy", date_time=_ZIP_DATE)
            zf.writestr(info, buf.getvalue())
    return out.getvalue()


def read_map_json(folder, kind: str = SPATIAL) -> dict:
    """``map.json`` of ``folder``, checked for format, version and ``kind``."""
    path = Path(folder) / MAP_JSON
    if Path(folder).is_file():
        raise InputError("is a file; a map is the folder that holds map.json", folder)
    if not Path(folder).is_dir():
        raise InputError("map folder not found", folder)
    if not path.is_file():
        raise InputError("not a complete map folder (no map.json)", path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"damaged map.json ({e})", path) from None
    except RecursionError:  # thousands of nested brackets
        raise InputError("damaged map.json (nested too deeply)", path) from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputError(f"not a {FORMAT} file", path)
    version = doc.get("version")
    if not isinstance(version, int) or version < 1:
        raise InputError(f"damaged map.json (version {version!r})", path)
    if version > FORMAT_VERSION:
        raise InputError(
            f"map format version {version} is newer than this graphslam reads "
            f"({FORMAT_VERSION}); upgrade graphslam",
            path,
        )
    found = doc.get("kind", SPATIAL)  # version-1 maps written before 2-D maps have none
    if not isinstance(found, str) or found not in _TABLES:
        raise InputError(f"damaged map.json (kind {quote(found)})", path)
    if found != kind:
        raise InputError(f"this is a {_KIND_TEXT[found]}; this run needs a {_KIND_TEXT[kind]}", path)
    for key in _TABLES[kind]:
        if not isinstance(doc.get(key), dict):
            raise InputError(f"damaged map.json (no {key!r} table)", path)
    doc.setdefault("meta", {})
    if not isinstance(doc["meta"], dict):  # no checksum covers map.json itself
        raise InputError("damaged map.json (meta)", path)
    sessions = doc["meta"].get("sessions", [])  # extended by a run with --map and --save-map
    if not isinstance(sessions, list) or not all(isinstance(s, dict) for s in sessions):
        raise InputError("damaged map.json (meta 'sessions' is not a list of tables)", path)
    for where, table in [
        ("meta", doc["meta"]),
        *((f"meta 'sessions' {i}", t) for i, t in enumerate(sessions)),
    ]:
        _check_meta_fields(table, where, path)
    return doc


def _check_meta_fields(table: dict, where: str, path: Path) -> None:
    """InputError for the fields of ``table`` (the map's meta or one session) a command
    reads as numbers or tables, given as something else (hostile pass 24: a frame range
    written "0:100:2", n_frames "fifty" or a config "isam2" were tracebacks, after the run)."""
    frames = table.get("frame_range")
    if frames is not None and not (
        isinstance(frames, list) and all(isinstance(v, int) and not isinstance(v, bool) for v in frames)
    ):
        raise InputError(f"damaged map.json ({where} 'frame_range' is not a list of whole numbers)", path)
    n = table.get("n_frames")
    if n is not None and (not isinstance(n, int) or isinstance(n, bool) or n < 0):
        raise InputError(f"damaged map.json ({where} 'n_frames' is not a whole number)", path)
    config = table.get("config")
    if config is not None and not (
        isinstance(config, dict) and all(isinstance(v, dict) for v in config.values())
    ):
        raise InputError(f"damaged map.json ({where} 'config' is not a table of sections)", path)


def _checked_bytes(folder: Path, entry: dict, what: str) -> tuple[Path, bytes]:
    name = str(entry.get("file", ""))
    path = inside_folder(folder, name)
    if path is None:  # a map names only its own files, never ../x or /etc/passwd
        raise InputError(
            f"damaged map.json ({what} file {quote(name)} is outside the map folder)", folder / MAP_JSON
        )
    if not path.is_file():
        raise InputError(f"map {what} file missing", path)
    data = path.read_bytes()
    if hashlib.sha256(data).hexdigest() != entry.get("sha256"):
        raise InputError(
            f"map {what} file is damaged, truncated or from another map (SHA-256 differs from map.json)", path
        )
    return path, data


def load_map(folder) -> SpatialMap:
    """Read a map folder written by :func:`save_map` (refusals in the module docstring)."""
    from loopclosure.vocabulary import load_vocabulary

    folder = Path(folder)
    doc = read_map_json(folder)
    npz_path, blob = _checked_bytes(folder, doc["arrays"], "array")
    vocab_path, vocab_bytes = _checked_bytes(folder, doc["vocabulary"], "vocabulary")
    arrays = _read_npz(blob, npz_path, _NAMES)
    try:
        K = np.array(doc["camera"]["K"], dtype=np.float64).reshape(3, 3)
        width, height = (_whole(v) for v in doc["camera"]["image_size"])  # exactly two
        size = (width, height)
    except (KeyError, TypeError, ValueError):
        raise InputError("damaged map.json (camera)", folder / MAP_JSON) from None
    if not np.all(np.isfinite(K)):
        raise InputError("damaged map.json (camera K not finite)", folder / MAP_JSON)
    if not (K[0, 0] > 0 and K[1, 1] > 0 and np.array_equal(K[2], [0.0, 0.0, 1.0])):
        # a hand-edited K (zeros) ended in numpy's "Singular matrix" traceback
        raise InputError("damaged map.json (camera K is no pinhole matrix)", folder / MAP_JSON)
    _check_distortion(
        doc["meta"].get("distortion") if isinstance(doc.get("meta"), dict) else None, folder / MAP_JSON
    )
    if min(size) < 1:  # else blamed on the images a localisation compares with it
        raise InputError(f"damaged map.json (camera image_size {width}x{height})", folder / MAP_JSON)
    _check_detectors(doc["meta"], folder / MAP_JSON)
    smap = SpatialMap(
        K=K,
        image_size=size,
        vocabulary=load_vocabulary(vocab_path),
        meta=doc["meta"],
        vocabulary_bytes=vocab_bytes,
        **arrays,
    )
    smap.check(npz_path)
    if smap.counts() != doc["counts"]:
        raise InputError(f"map arrays hold {smap.counts()}, map.json says {doc['counts']}", npz_path)
    return smap


def _whole(value) -> int:
    """``value`` as an int; ValueError for a fraction (``int(640.5)`` silently gave 640)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value):
        raise ValueError(value)
    return int(value)


#: Distortion coefficient counts OpenCV's camera models take (k1 k2 p1 p2 [k3 [k4-k6 [s1-s4
#: [tx ty]]]]).
DISTORTION_COUNTS = (4, 5, 8, 12, 14)


def _check_distortion(distortion, path: Path) -> None:
    """InputError naming ``path`` unless ``distortion`` (map.json ``meta.distortion``) is
    absent, empty, or a list of finite numbers of a count OpenCV takes: ``map.json`` is not covered
    by the arrays' checksum, and an edited ``[-0.034]`` (k1 alone, as COLMAP's SIMPLE_RADIAL
    gives it) ended in OpenCV's traceback when a localisation compared cameras."""
    if distortion is None:
        return
    try:
        values = np.asarray(distortion, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        values = None
    if values is None or values.size not in (0, *DISTORTION_COUNTS) or not np.all(np.isfinite(values)):
        raise InputError(
            f"damaged map.json (camera distortion {str(distortion)[:80]}: "
            f"{', '.join(map(str, DISTORTION_COUNTS))} finite numbers, as OpenCV takes them)",
            path,
        )


def _check_detectors(meta: dict, path: Path) -> None:
    """InputError naming ``path`` unless the detectors a localizer builds from ``meta``
    (``tracker.detector``, the ``bow_orb`` ORB settings) are valid settings."""
    from frontend.orb import OrbConfig
    from frontend.tracking_config import TrackerConfig
    from slamcore.config import from_dict

    tracker, bow_orb = meta.get("tracker", {}), meta.get("bow_orb", {})
    for key, value in (("tracker", tracker), ("bow_orb", bow_orb)):
        if not isinstance(value, dict):
            raise InputError(f"damaged map.json (meta {key!r} is not a table)", path)
    try:
        TrackerConfig(detector=tracker.get("detector", "harris"))
        from_dict(OrbConfig, bow_orb)
    except ConfigError as e:
        raise InputError(f"damaged map.json (meta: {e})", path) from None


def _read_npz(blob: bytes, npz_path: Path, names) -> dict[str, np.ndarray]:
    try:
        check_npz_sizes(io.BytesIO(blob), npz_path)  # before np.load allocates
        with np.load(io.BytesIO(blob), allow_pickle=False) as z:
            arrays = {name: z[name] for name in names}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError) as e:
        raise InputError(f"damaged map arrays ({type(e).__name__}: {e})", npz_path) from None
    for name, a in arrays.items():
        if a.ndim == 0:  # every array has a row per keyframe, landmark or observation
            raise InputError(f"map array {name} is a single value, not rows", npz_path)
    return arrays


def load_planar_map(folder) -> PlanarMap:
    """Read a 2-D map folder written by :func:`save_planar_map` (refusals in the module
    docstring; a 3-D map is refused)."""
    folder = Path(folder)
    doc = read_map_json(folder, PLANAR)
    npz_path, blob = _checked_bytes(folder, doc["arrays"], "array")
    pmap = PlanarMap(meta=doc["meta"], **_read_npz(blob, npz_path, PLANAR_ARRAYS))
    pmap.check(npz_path)
    if pmap.counts() != doc["counts"]:
        raise InputError(f"map arrays hold {pmap.counts()}, map.json says {doc['counts']}", npz_path)
    return pmap


def check_camera(smap: SpatialMap, K: np.ndarray, image_size, where, distortion=None) -> None:
    """InputError unless ``K``, ``distortion`` and ``image_size`` are the camera the map was
    built with: no pixel of the image moves by more than :data:`CAMERA_TOL_PX` between
    the two. The map's distortion is ``meta["distortion"]``; a map saved before it was
    recorded says so where this camera has one (a map built with one lens model was
    used with another, silent: thirteenth hostile pass)."""
    size = tuple(int(v) for v in image_size)
    if size != tuple(smap.image_size):
        raise InputError(
            f"map was built with {smap.image_size[0]}x{smap.image_size[1]} images, "
            f"this sequence's are {size[0]}x{size[1]}",
            where,
        )
    mine = _coefficients(distortion)
    if "distortion" not in smap.meta and np.any(mine != 0):
        raise InputError(
            "map does not record its camera's lens distortion (saved by an older graphslam) and "
            "this sequence has one: rebuild the map with --save-map",
            where,
        )
    moved = camera_difference_px(smap.K, _coefficients(smap.meta.get("distortion")), K, mine, size)
    if not moved <= CAMERA_TOL_PX:  # NaN intrinsics differ too
        raise InputError(
            f"map was built with another camera (its pixels lie up to {moved:.3g} px from this one's)", where
        )


def _coefficients(distortion) -> np.ndarray:
    """OpenCV distortion coefficients as a float64 vector (none: empty)."""
    return np.zeros(0) if distortion is None else np.asarray(distortion, dtype=np.float64).reshape(-1)


def camera_difference_px(K_a, dist_a, K_b, dist_b, image_size) -> float:
    """Largest distance (pixels) between where cameras a and b image the same rays: the
    rays of a grid over the image (border included) through camera a's pinhole, each
    projected by both cameras' full models. Forward projection only: undistorting
    pixels is iterative and does not converge past the fold of a strong lens model."""
    import cv2

    w, h = image_size
    K_a, K_b = np.asarray(K_a, np.float64), np.asarray(K_b, np.float64)
    if not (np.all(np.isfinite(K_a)) and np.all(np.isfinite(K_b))):
        return float("nan")
    u, v = np.meshgrid(np.linspace(0, w - 1, 17), np.linspace(0, h - 1, 17))
    rays = np.linalg.solve(K_a, np.stack([u.ravel(), v.ravel(), np.ones(u.size)])).T
    zero = np.zeros(3)
    a, _ = cv2.projectPoints(rays, zero, zero, K_a, dist_a if dist_a.size else None)
    b, _ = cv2.projectPoints(rays, zero, zero, K_b, dist_b if dist_b.size else None)
    return float(np.max(np.linalg.norm(a.reshape(-1, 2) - b.reshape(-1, 2), axis=1)))
