"""The vocabulary file format: one ``.npz`` per vocabulary, written and read back bit for bit.

A file holds ``format_version`` (:data:`FORMAT_VERSION`), ``kind``
(``"FlatVocabulary"`` or ``"VocabularyTree"``), the estimator's parameters
and its learned arrays (:func:`flat_arrays`, :func:`tree_arrays`).
:func:`save_npz` writes exactly the given path (no suffix added); reading
(:func:`read_npz`, :func:`read_kind`, then :func:`restore_flat` or
:func:`restore_tree`) gives arrays identical to the saved ones (same dtype,
same bits) and raises :class:`slamcore.errors.InputError` naming the file
when it is missing, damaged, truncated, of another format version, of
another kind or internally inconsistent.

The estimator classes live in :mod:`loopclosure.vocabulary`, which imports
this module; the restore functions take the class to build as an argument.
"""

from __future__ import annotations

import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from slamcore.errors import InputError
from slamcore.npz import check_npz_sizes

FORMAT_VERSION = 1


def save_npz(path, kind: str, arrays: dict) -> None:
    """Write ``arrays`` with the format version and ``kind`` as one .npz at exactly ``path``."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a folder: give the vocabulary file's name", path)
    # A file handle, so numpy does not append ".npz" to the name.
    try:
        with open(path, "wb") as fh:
            np.savez(fh, format_version=np.int64(FORMAT_VERSION), kind=np.str_(kind), **arrays)
    except OSError as exc:
        if path.is_file():  # a half-written file (a full disk) would load as damaged
            path.unlink()
        raise InputError(f"cannot write the vocabulary: {exc.strerror or exc}", path) from None


def read_npz(path) -> dict:
    """Read every array of a vocabulary file into a dict; InputError on any damage."""
    path = Path(path)
    if not path.is_file():
        raise InputError("vocabulary file not found", path)
    _refuse_other_formats(path)
    try:
        check_npz_sizes(path, path)  # before np.load allocates what a header declares
        with np.load(path, allow_pickle=False) as z:
            data = {name: z[name] for name in z.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, KeyError, TypeError, AttributeError) as exc:
        # A plain .npy has no .files and no context manager; other damage surfaces
        # as zip, CRC, header or reshape errors.
        raise InputError(
            f"damaged or unreadable vocabulary file ({type(exc).__name__}: {exc})", path
        ) from exc
    if "format_version" not in data or "kind" not in data:
        raise InputError("not a vocabulary file (no format_version/kind)", path)
    try:
        version = int(data["format_version"])
    except (TypeError, ValueError, OverflowError) as exc:  # inf: OverflowError
        raise InputError("bad format_version field", path) from exc
    if version != FORMAT_VERSION:
        raise InputError(
            f"vocabulary format version {version}, this code reads version {FORMAT_VERSION}", path
        )
    data["kind"] = str(data["kind"])
    return data


#: First bytes of the files other vocabulary tools write: a user who has DBoW2/DBoW3 or
#: ORB-SLAM's vocabulary tries it first (the slambook2 desk data ships a DBoW3 .yml.gz).
_OTHER_FORMATS = ((b"\x1f\x8b", "gzip-compressed"), (b"%YAML", "YAML text"), (b"vocabulary:", "YAML text"))


def _refuse_other_formats(path: Path) -> None:
    """InputError naming what the file is, when it is no zip (every .npz is one) and starts
    like another tool's vocabulary or like text; a damaged .npz is left to the reader."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
    except OSError as e:
        raise InputError(f"cannot read vocabulary file ({e.strerror})", path) from None
    if head.startswith(b"PK"):
        return
    what = next((name for magic, name in _OTHER_FORMATS if head.startswith(magic)), None)
    if what is None and head and all(32 <= b < 127 or b in b"\t\r\n" for b in head):
        what = "text"
    if what is not None:
        raise InputError(
            f"not a graphslam vocabulary: the file is {what}; graphslam reads the .npz files "
            "'graphslam vocab train' writes (DBoW2/DBoW3 and ORB-SLAM vocabularies are not read)",
            path,
        )


def read_kind(path, kind: str) -> dict:
    """:func:`read_npz`, refusing a file that holds another kind of vocabulary."""
    data = read_npz(path)
    if data["kind"] != kind:
        raise InputError(f"file holds a {data['kind']}, not a {kind}", path)
    return data


def _require(data: dict, names: Sequence[str], path) -> None:
    """InputError naming the fields of ``names`` missing from ``data``."""
    missing = [n for n in names if n not in data]
    if missing:
        raise InputError(f"vocabulary file lacks field(s) {', '.join(missing)}", path)


#: Each kind's estimator parameters, in file order, with the type each is read back as
#: (written as the numpy scalar of :data:`_STORED_AS`).
FLAT_PARAMS = (("n_words", int), ("seed", int), ("max_iter", int), ("minibatch", bool), ("n_init", int))
TREE_PARAMS = (
    ("branching", int),
    ("depth", int),
    ("seed", int),
    ("max_iter", int),
    ("max_node_samples", int),
    ("init", str),
    ("n_init", int),
)
_STORED_AS = {int: np.int64, bool: np.bool_, str: np.str_}

#: The learned fields both kinds end with, in file order, with the type each is read
#: back as (None: an array kept as it is); the estimator holds each as ``name_``.
COMMON_LEARNED = (("metric", str), ("descriptor_dim", int), ("idf", None), ("n_training_images", int))
COMMON_FIELDS = tuple(name for name, _ in COMMON_LEARNED)


def _common_arrays(v) -> dict:
    """The fields of :data:`COMMON_LEARNED` of a fitted vocabulary ``v``."""
    return {
        name: getattr(v, name + "_") if kind is None else _STORED_AS[kind](getattr(v, name + "_"))
        for name, kind in COMMON_LEARNED
    }


def _param_arrays(v, params) -> dict:
    """The parameters ``params`` (name, type) of estimator ``v`` as numpy scalars."""
    return {name: _STORED_AS[kind](getattr(v, name)) for name, kind in params}


def _built(cls, data: dict, params):
    """A ``cls`` made with the parameters ``params`` (name, type) read from ``data``."""
    return cls(**{name: kind(data[name]) for name, kind in params})


def _restore_common(v, data: dict) -> None:
    """Set the fields of :data:`COMMON_LEARNED` of ``v`` from ``data`` (their checks follow)."""
    for name, kind in COMMON_LEARNED:
        setattr(v, name + "_", data[name] if kind is None else kind(data[name]))


def _check_centres(v, n_rows: int, path) -> None:
    """Centres dtype/shape agree with the metric and descriptor width; IDF finite, >= 0."""
    want = np.uint8 if v.metric_ == "hamming" else np.float32
    ok = (
        v.metric_ in ("hamming", "euclidean")
        and v.centres_.dtype == want
        and v.centres_.shape == (n_rows, v.descriptor_dim_)
        and v.idf_.shape == (v.n_words_,)
        and bool(np.all(np.isfinite(v.idf_)))
        and bool(np.all(v.idf_ >= 0.0))
    )
    if not ok:
        raise InputError("inconsistent arrays in vocabulary file", path)


# ----------------------------------------------------------------------------
# flat vocabulary


def flat_arrays(v) -> dict:
    """The fields of a fitted :class:`loopclosure.vocabulary.FlatVocabulary` ``v``, in file order."""
    return {**_param_arrays(v, FLAT_PARAMS), "centres": v.centres_, **_common_arrays(v)}


def restore_flat(cls, data: dict, path):
    """A ``cls`` (FlatVocabulary) rebuilt from the fields ``data`` of file ``path``, checked."""
    _require(data, [*(name for name, _ in FLAT_PARAMS), "centres", *COMMON_FIELDS], path)
    try:
        v = _built(cls, data, FLAT_PARAMS)
        v.centres_ = data["centres"]
        v.n_words_ = int(data["n_words"])
        _restore_common(v, data)
    except (TypeError, ValueError, OverflowError) as exc:  # int(inf): OverflowError
        raise InputError(f"bad vocabulary field ({exc})", path) from exc
    if v.idf_.dtype != np.float64:
        raise InputError("inconsistent arrays in vocabulary file", path)
    _check_centres(v, v.n_words_, path)
    return v


# ----------------------------------------------------------------------------
# vocabulary tree


def tree_arrays(v) -> dict:
    """The fields of a fitted :class:`loopclosure.vocabulary.VocabularyTree` ``v``, in file order."""
    return {
        **_param_arrays(v, TREE_PARAMS),
        "centres": v.centres_,
        "children": v.children_,
        "node_word": v.node_word_,
        "word_node": v.word_node_,
        **_common_arrays(v),
    }


def restore_tree(cls, data: dict, path):
    """A ``cls`` (VocabularyTree) rebuilt from the fields ``data`` of file ``path``, checked."""
    learned = ["centres", "children", "node_word", "word_node", *COMMON_FIELDS]
    _require(data, [*(name for name, _ in TREE_PARAMS), *learned], path)
    try:
        v = _built(cls, data, TREE_PARAMS)
        v.centres_ = data["centres"]
        v.children_ = data["children"]
        v.node_word_ = data["node_word"]
        v.word_node_ = data["word_node"]
        v.n_words_ = int(v.word_node_.size)
        _restore_common(v, data)
    except (TypeError, ValueError, OverflowError) as exc:  # int(inf): OverflowError
        raise InputError(f"bad vocabulary field ({exc})", path) from exc
    _check_tree(v, path)
    return v


def _is_tree(children: np.ndarray) -> bool:
    """``children`` links form one tree rooted at node 0: the root has no parent,
    every other node exactly one, with a smaller index (nodes are numbered
    breadth first), so no link leads back up and a descent always ends."""
    rows, _ = np.nonzero(children >= 0)
    targets = children[children >= 0].astype(np.int64)
    parents = np.bincount(targets, minlength=children.shape[0])
    return bool(np.all(targets > rows) and parents[0] == 0 and np.all(parents[1:] == 1))


def _check_tree(v, path) -> None:
    """The tree's arrays agree: int32 links within range, words exactly the leaves."""
    ch, nw, wn = v.children_, v.node_word_, v.word_node_
    n_nodes = ch.shape[0] if ch.ndim == 2 else -1
    ok = (
        ch.dtype == np.int32
        and nw.dtype == np.int32
        and wn.dtype == np.int32
        and v.idf_.dtype == np.float64
        and n_nodes >= 1
        and ch.shape[1] == v.branching
        and nw.shape == (n_nodes,)
        and wn.ndim == 1
        and bool(np.all((ch >= -1) & (ch < n_nodes)))
        and bool(np.all((wn >= 0) & (wn < n_nodes)))
    )
    ok = ok and _is_tree(ch)
    # Every leaf (no child) is a word and every word a leaf, numbered in node order.
    ok = (
        ok
        and np.array_equal(np.flatnonzero((ch < 0).all(axis=1)), wn)
        and np.array_equal(nw[wn], np.arange(wn.size))
        and int((nw >= 0).sum()) == wn.size
    )
    if not ok:
        raise InputError("inconsistent arrays in vocabulary file", path)
    _check_centres(v, n_nodes, path)
