"""Random forests as plain numeric arrays (`.npz`, read with allow_pickle=False): a model file that cannot run
code, unlike a pickle/joblib.

A forest file holds the scikit-learn trees' node arrays (children, feature, threshold, impurity, sample
counts, missing-value side) and leaf values, concatenated over the trees, with `tree_nodes` (nodes per tree),
`tree_depth` and a JSON `meta` (kind, n_features, classes, the forest's hyper-parameters). Loading checks every
array's type and shape and every tree's structure (children after their parent and inside the tree, split
features inside the feature vector, finite thresholds and values) before it builds scikit-learn estimators
from them, so a crafted or damaged file is a DataError (exit 2), never a crash or code run.
"""

from __future__ import annotations

import io
import json
import zipfile
import zlib

import numpy as np

from .errors import DataError

FORMAT = "impactsense-forest-1"
_INT_FIELDS = ("left_child", "right_child", "feature", "n_node_samples")
_FLOAT_FIELDS = ("threshold", "impurity", "weighted_n_node_samples")
_PARAMS = ("n_estimators", "max_depth", "min_samples_leaf", "min_samples_split", "max_features", "criterion",
           "random_state", "class_weight", "bootstrap")


def _json_safe(v):
    return v if v is None or isinstance(v, (bool, int, float, str)) else str(v)


def save_forest(target, forest) -> None:
    """Writes a fitted RandomForestRegressor (one output) or RandomForestClassifier to `target` (a path or
    binary file)."""
    classifier = hasattr(forest, "classes_")
    states = [t.tree_.__getstate__() for t in forest.estimators_]
    nodes = np.concatenate([s["nodes"] for s in states])
    meta = {"format": FORMAT, "kind": "classifier" if classifier else "regressor",
            "n_features": int(forest.n_features_in_), "n_outputs": int(forest.n_outputs_),
            "classes": [c.item() if hasattr(c, "item") else c for c in forest.classes_] if classifier else None,
            "params": {k: _json_safe(forest.get_params().get(k)) for k in _PARAMS}}
    arrays = {f: np.ascontiguousarray(nodes[f]) for f in (*_INT_FIELDS, *_FLOAT_FIELDS)}
    arrays["missing_go_to_left"] = np.ascontiguousarray(nodes["missing_go_to_left"]).astype(np.uint8)
    arrays["values"] = np.concatenate([s["values"] for s in states]).astype(np.float64)
    arrays["tree_nodes"] = np.array([s["node_count"] for s in states], np.int64)
    arrays["tree_depth"] = np.array([s["max_depth"] for s in states], np.int64)
    np.savez(target, meta=np.array(json.dumps(meta)), **arrays)


def read_arrays(path, data: bytes | None, what: str) -> dict:
    """The arrays of the .npz in `path` (or in `data`, its bytes), never unpickling anything; an unreadable
    or truncated file is a DataError naming it as `what`."""
    try:
        with np.load(io.BytesIO(data) if data is not None else path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, zlib.error, OSError, ValueError, EOFError, KeyError, RuntimeError) as exc:
        raise DataError(path, None, f"not a {what} (unreadable or truncated: {exc})") from None


def load_forest(path, data: bytes | None = None):
    """The forest in `path` (or in `data`, the file's bytes, already read and checked by the caller)."""
    arrays = read_arrays(path, data, "forest file")
    try:
        return _build(arrays)
    except (KeyError, TypeError, ValueError, IndexError, OverflowError, AttributeError, RecursionError) as exc:
        raise DataError(path, None, f"not a valid forest file ({type(exc).__name__}: {exc})") from None


def _array(arrays, name, kind: str) -> np.ndarray:
    a = arrays[name]
    if a.dtype.kind not in kind or a.ndim < 1:
        raise ValueError(f"{name}: expected a numeric array, got {a.dtype} {a.shape}")
    return a


def _build(arrays: dict):
    meta = json.loads(str(arrays["meta"][()]))
    if not isinstance(meta, dict) or meta.get("format") != FORMAT or meta.get("kind") not in ("regressor",
                                                                                               "classifier"):
        raise ValueError(f"meta: not a {FORMAT} file")
    n_features, n_outputs = int(meta["n_features"]), int(meta["n_outputs"])
    classifier = meta["kind"] == "classifier"
    classes = np.asarray(meta["classes"]) if classifier else None
    if not 0 < n_features < 100000 or n_outputs != 1 or (classifier and not 2 <= len(classes) <= 1000):
        raise ValueError("meta: n_features, n_outputs or classes out of range")
    counts = _array(arrays, "tree_nodes", "iu").astype(np.int64)
    depth = _array(arrays, "tree_depth", "iu").astype(np.int64)
    fields = {f: _array(arrays, f, "iu") for f in _INT_FIELDS}
    fields.update({f: _array(arrays, f, "f") for f in _FLOAT_FIELDS})
    fields["missing_go_to_left"] = _array(arrays, "missing_go_to_left", "iub")
    values = _array(arrays, "values", "f").astype(np.float64)
    total = int(counts.sum())
    n_cls = len(classes) if classifier else 1
    if (counts.ndim != 1 or counts.size == 0 or counts.min() < 1 or depth.shape != counts.shape
            or any(a.shape != (total,) for a in fields.values()) or values.shape != (total, 1, n_cls)
            or not np.isfinite(values).all()):
        raise ValueError("array shapes do not agree with tree_nodes")
    params = {k: v for k, v in (meta.get("params") or {}).items() if k in _PARAMS}
    trees, start = [], 0
    for n, d in zip(counts.tolist(), depth.tolist()):
        part = {f: a[start:start + n] for f, a in fields.items()}
        _check_tree(part, n, n_features)
        trees.append(_tree(part, values[start:start + n], n, int(d), n_features, n_cls, classifier, classes))
        start += n
    from sklearn.ensemble import RandomForestClassifier, RandomForestRegressor   # here: every CLI command
    # imports this module (export's options), and most never build a forest

    forest = (RandomForestClassifier if classifier else RandomForestRegressor)()
    forest.set_params(**_settable(forest, params), n_estimators=len(trees))
    forest.estimators_ = trees
    forest.estimator_ = trees[0]
    forest.n_features_in_ = n_features
    forest.n_outputs_ = 1
    if classifier:
        forest.classes_ = classes
        forest.n_classes_ = len(classes)
    return forest


def _settable(est, params: dict) -> dict:
    ok = est.get_params()
    out = {}
    for k, v in params.items():
        if k in ok and k != "n_estimators" and (v is None or isinstance(v, (bool, int, float, str))):
            out[k] = v
    if isinstance(out.get("class_weight"), str) and out["class_weight"] not in ("balanced", "balanced_subsample"):
        out.pop("class_weight")
    return out


def _check_tree(part: dict, n: int, n_features: int) -> None:
    """Every split node's children lie after it and inside the tree, its feature inside the feature vector and
    its threshold finite; leaves have no children. Such a tree is walked to a leaf in at most n steps."""
    left, right, feat = (part[k].astype(np.int64) for k in ("left_child", "right_child", "feature"))
    idx = np.arange(n)
    leaf = left == -1
    if not np.array_equal(leaf, right == -1):
        raise ValueError("a node has one child")
    split = ~leaf
    if ((left[split] <= idx[split]) | (left[split] >= n) | (right[split] <= idx[split]) | (right[split] >= n)).any():
        raise ValueError("a child index lies outside its tree or before its parent")
    if ((feat[split] < 0) | (feat[split] >= n_features)).any():
        raise ValueError("a split reads a feature outside the feature vector")
    if not np.isfinite(part["threshold"][split]).all():
        raise ValueError("a split threshold is not finite")


def _tree(part: dict, values: np.ndarray, n: int, depth: int, n_features: int, n_cls: int, classifier: bool,
          classes):
    from sklearn.tree import DecisionTreeClassifier, DecisionTreeRegressor
    from sklearn.tree._tree import NODE_DTYPE, Tree

    nodes = np.zeros(n, dtype=NODE_DTYPE)
    for f in NODE_DTYPE.names:
        nodes[f] = part[f]
    tree = Tree(n_features, np.array([n_cls], dtype=np.intp), 1)
    tree.__setstate__({"max_depth": max(depth, 0), "node_count": n, "nodes": nodes,
                       "values": np.ascontiguousarray(values)})
    est = DecisionTreeClassifier() if classifier else DecisionTreeRegressor()
    est.tree_ = tree
    est.n_features_in_ = n_features
    est.n_outputs_ = 1
    est.max_features_ = n_features
    if classifier:
        est.classes_ = classes
        est.n_classes_ = n_cls
    return est
