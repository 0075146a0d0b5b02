"""The board's C from exported forests (`export`): node tables, the twin's arrays, the model card's signal
settings and m2cgen's per-tree functions, all in float32.

Thresholds are scikit-learn's float64 split points rounded *down* to float32: for float32 inputs
`x <= t32` decides exactly as scikit-learn's `float64(x) <= t`.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

import numpy as np

from .errors import ImpactSenseError
from .height_class import linear_c, linear_tables
from .signal import FIELDS, card_values, settings

if TYPE_CHECKING:
    from .export import ModelSet

LEAF = 0xFF   # impactapp kLeaf: a linear model's unused factor slot


class ExportError(ImpactSenseError):
    """An export that cannot be written (a model folder's problem, or C the board could not run)."""


# --- float32 helpers ---

def f32_floor(t: np.ndarray) -> np.ndarray:
    """Largest float32 <= each float64 value."""
    t = np.asarray(t, dtype=np.float64)
    t32 = t.astype(np.float32)
    up = t32.astype(np.float64) > t
    t32[up] = np.nextafter(t32[up], np.float32(-np.inf))
    return t32


def _c_float(v) -> str:
    v = np.float32(v)
    if not np.isfinite(v):
        raise ExportError(f"non-finite constant {v} in a tree")
    text = f"{float(v):.9g}"
    if not any(ch in text for ch in ".e"):
        text += ".0"
    return text + "f"


# --- node tables ---

def _leaf_values(tree, classifier: bool) -> np.ndarray:
    v = tree.value[:, 0, :]
    if classifier:
        s = v.sum(axis=1, keepdims=True)
        s[s == 0] = 1
        return (v / s)[:, 1]
    return v[:, 0]


# a forest's arrays (impactapp forest.h) in the C struct's order; a linear model has roots, feature and value only
TABLE_KEYS = ("roots", "feature", "threshold", "skip", "leaf", "leaf_value", "value")


def order_key(v) -> np.ndarray:
    """impactapp::order_key: float32 bits as int32 keys that order as the floats do (negative: magnitude bits
    flipped), so the board compares thresholds as integers."""
    b = np.asarray(v, dtype=np.float32).view(np.int32)
    return (b ^ ((b >> 31) & np.int32(0x7FFFFFFF))).astype(np.int32)


def _preorder(tree) -> np.ndarray:
    """The tree's node ids in preorder (node, left subtree, right subtree)."""
    left, right = tree.children_left, tree.children_right
    order, stack = [], [0]
    while stack:
        n = stack.pop()
        order.append(n)
        if left[n] != -1:
            stack += [right[n], left[n]]
    return np.asarray(order, dtype=np.int64)


def _tree_arrays(tree, classifier: bool) -> tuple:
    """One tree as (feature, threshold keys, skip, leaf values) in forest.h's layout: split nodes and leaves apart,
    each in preorder; skip = the leaves under the left child."""
    left, right = tree.children_left, tree.children_right
    is_leaf = left == -1
    order = _preorder(tree)
    leaves_under = np.ones(tree.node_count, dtype=np.int64)
    for n in order[::-1]:       # children before their parent
        if not is_leaf[n]:
            leaves_under[n] = leaves_under[left[n]] + leaves_under[right[n]]
    split = order[~is_leaf[order]]
    values = _leaf_values(tree, classifier).astype(np.float32)[order[is_leaf[order]]]
    if split.size == 0:   # a single leaf: one split node whose two children are that leaf
        return np.zeros(1, np.uint8), order_key(0.0).reshape(1), np.ones(1, np.uint16), np.repeat(values, 2)
    if np.any(tree.feature[split] >= LEAF):
        raise ExportError("more than 254 features")
    skip = leaves_under[left[split]]
    if skip.max() > 0xFFFF:
        raise ExportError(f"a left subtree of {int(skip.max())} leaves exceeds the u16 skip")
    threshold = f32_floor(tree.threshold[split]) + np.float32(0.0)   # -0 -> +0: the same decisions, one key
    return tree.feature[split].astype(np.uint8), order_key(threshold), skip.astype(np.uint16), values


def forest_tables(forest, n_trees: int | None = None) -> dict:
    """The first n_trees trees of a fitted forest as impactapp's arrays (forest.h: split nodes and leaves apart,
    thresholds as order keys, each leaf an index into the forest's distinct leaf values; see the module doc)."""
    classifier = hasattr(forest, "predict_proba")
    trees = forest.estimators_[: n_trees or len(forest.estimators_)]
    parts = [_tree_arrays(est.tree_, classifier) for est in trees]
    values = np.concatenate([p[3] for p in parts])
    distinct, leaf = np.unique(values, return_inverse=True)
    if distinct.size > 0x10000:
        raise ExportError(f"{distinct.size} distinct leaf values exceed the u16 leaf index")
    return {
        "roots": np.cumsum([0] + [len(p[0]) for p in parts]).astype(np.int32),
        "feature": np.concatenate([p[0] for p in parts]).astype(np.uint8),
        "threshold": np.concatenate([p[1] for p in parts]).astype(np.int32),
        "skip": np.concatenate([p[2] for p in parts]).astype(np.uint16),
        "leaf": leaf.astype(np.uint16).ravel(),
        "leaf_value": distinct.astype(np.float32),
    }


def table_nodes(tables: dict) -> int:
    """A forest's nodes (split nodes and leaves; a linear model's factor slots)."""
    return int(tables["feature"].size + tables.get("leaf", np.empty(0)).size)


def table_bytes(tables: dict | None) -> int:
    """Flash bytes of a forest's node tables (or of the twin's arrays; 0 for None)."""
    return int(sum(np.asarray(a).nbytes for a in tables.values())) if tables else 0


def _c_array(ctype: str, name: str, values, fmt) -> str:
    vals = [fmt(v) for v in np.asarray(values).tolist()]
    rows = [", ".join(vals[i:i + 8]) for i in range(0, len(vals), 8)]
    body = ",\n  ".join(rows)
    return f"static const {ctype} {name}[{max(len(vals), 1)}] = {{\n  {body}\n}};\n"


def exported_fields():
    """The signal and localiser fields a model card hands the board, in impactcore.h's order: all but the
    acquisition's own (ADC rails), which the board knows itself."""
    return [f for f in FIELDS.values() if f.role != "ACQUISITION"]


def signal_struct_c() -> str:
    """The C struct `impactsense_signal_config` (impactsense_models.h), one member per exported field."""
    lines = [f"  {f.c_type} {f.name}{f'[{f.count}]' if f.count > 1 else ''};  // {f.role.lower()}"
             for f in exported_fields()]
    return "typedef struct {\n" + "\n".join(lines) + "\n} impactsense_signal_config;\n"


def signal_c(signal: dict) -> str:
    """The model card's signal settings as the initializer of `impactsense_signal` (defaults for absent keys)."""
    values = settings(**card_values(signal))
    vals = []
    for f in exported_fields():
        fmt = (lambda v: str(int(v))) if f.type == "int" else _c_float
        v = values[f.name]
        vals.append("{" + ", ".join(fmt(x) for x in v) + "}" if f.count > 1 else fmt(v))
    return "const impactsense_signal_config impactsense_signal = {\n  " + ",\n  ".join(vals) + "\n};\n"


_C_TYPES = {"roots": ("int32_t", str), "feature": ("uint8_t", str), "threshold": ("int32_t", str),
            "skip": ("uint16_t", str), "leaf": ("uint16_t", str), "leaf_value": ("float", _c_float),
            "value": ("float", _c_float)}


def forest_c(name: str, t: dict) -> tuple[str, str]:
    """(the arrays of one forest's tables, or of a linear model's: roots, feature, value only; the initializer of its
    impactsense_forest: absent arrays are null pointers)."""
    arrays = "".join(_c_array(_C_TYPES[k][0], f"{name}_{k}", t[k], _C_TYPES[k][1]) for k in TABLE_KEYS if k in t)
    n_trees = len(t["roots"]) - ("leaf" in t)   # a forest's roots end with its split-node count
    init = ", ".join([str(n_trees)] + [f"{name}_{k}" if k in t else "0" for k in TABLE_KEYS])
    return arrays, "{" + init + "}"


def tables_c(tabs: dict[str, dict], models, header: str) -> str:
    out = [header, '#include "impactsense_models.h"\n\n']
    empty = "{" + ", ".join(["0"] * (1 + len(TABLE_KEYS))) + "}"
    for role, t in tabs.items():
        # The m2cgen build (IMPACTSENSE_MODELS_M2CGEN) keeps the inputs and drops the node tables.
        arrays, init = forest_c(role, t)
        inputs = _c_array("uint8_t", f"{role}_inputs", models.inputs[role], str)
        n_inputs = len(models.inputs[role])
        out.append("#ifndef IMPACTSENSE_MODELS_M2CGEN\n")
        out.append(arrays + inputs)
        out.append(f"const impactsense_model impactsense_model_{role} = {{{init}, {role}_inputs, {n_inputs}}};\n")
        out.append("#else\n")
        out.append(inputs)
        out.append(f"const impactsense_model impactsense_model_{role} = {{{empty}, {role}_inputs, {n_inputs}}};\n"
                   "#endif\n\n")
    if models.twin is not None:
        out.append(twin_c(models.twin))
    if models.three_channel:
        out.append(three_channel_c({c: linear_tables(m) for c, m in models.three_channel.items()}))
    if models.three_position:
        out.append(three_position_c(three_position_tables(models.three_position)))
    out.append(signal_c(models.signal))
    return "".join(out)


def three_channel_c(tabs: dict) -> str:
    """The three-channel classes (height_class.linear_tables of each channel left out) as
    impactsense_model_energy_without[4], in both builds (the m2cgen one runs them as tables too)."""
    out, models = [], []
    for c in range(4):
        arrays, init = forest_c(f"without_{c}", tabs[c])
        out.append(arrays)
        models.append(f"{{{init}, 0, {THREE_CHANNEL_INPUTS}}}")
    out.append("const impactsense_model impactsense_model_energy_without[4] = {\n  " + ",\n  ".join(models)
               + "\n};\n\n")
    return "".join(out)


def three_position_c(tabs: dict) -> str:
    """The three-sensor position's pairs (channel -> (x tables, y tables); forest_tables) as
    impactsense_model_position_without[8] (channel c's x at 2c, y at 2c + 1; a channel without a pair: 0 trees),
    in both builds (the m2cgen one runs them as tables too)."""
    out, models = [], []
    empty = "{" + ", ".join(["0"] * (1 + len(TABLE_KEYS))) + "}"
    for c in range(4):
        for axis, t in zip("xy", tabs.get(c, (None, None))):
            if t is None:
                models.append(f"{{{empty}, 0, {THREE_POSITION_INPUTS}}}")
                continue
            arrays, init = forest_c(f"position_{axis}_without_{c}", t)
            out.append(arrays)
            models.append(f"{{{init}, 0, {THREE_POSITION_INPUTS}}}")
    out.append("const impactsense_model impactsense_model_position_without[8] = {\n  " + ",\n  ".join(models)
               + "\n};\n\n")
    return "".join(out)


def three_position_header(models) -> tuple[str, str]:
    """(the header's define, its declaration) of the three-sensor position's pairs; empty without them."""
    return (THREE_POSITION_DEFINE, THREE_POSITION_DECL) if models.three_position else ("", "")


def three_position_tables(pairs: dict) -> dict:
    """channel -> (x tables, y tables) of the three-sensor position's pairs (forest_tables); {} without them."""
    return {c: tuple(forest_tables(f) for f in pair) for c, pair in sorted(pairs.items())}


def pairs_bytes(pairs: dict) -> int:
    """Flash bytes of the three-sensor position's pairs' tables (channel -> (forest dx, forest dy))."""
    return sum(table_bytes(t) for tabs in three_position_tables(pairs).values() for t in tabs)


def three_position_npz(pairs: dict) -> dict:
    """The emulator's copy of the three-sensor position's pairs (channel -> (forest dx, forest dy))."""
    return {f"position_{a}_without_{c}_{k}": v for c, tabs in three_position_tables(pairs).items()
            for a, t in zip("xy", tabs) for k, v in t.items()}


def three_position_from_npz(z) -> dict:
    """channel -> (x tables, y tables) from an export's forest_tables.npz (a channel without a pair: absent)."""
    return {c: tuple({k: z[f"position_{a}_without_{c}_{k}"] for k in TABLE_KEYS
                      if f"position_{a}_without_{c}_{k}" in z.files} for a in "xy")
            for c in range(4) if f"position_x_without_{c}_roots" in z.files}


def three_position_binding(tabs: dict, channels=True) -> list | None:
    """The 8 node tables `_link.ForestModels` takes (channel c's x at 2c, y at 2c + 1; a channel without a pair or
    not in `channels`, True: all, False: none: 0 trees), or None without any."""
    keep = set(range(4)) if channels is True else set(channels or ())
    if not tabs or not keep:
        return None
    empty = {"roots": [0], "feature": [], "threshold": [], "skip": [], "leaf": [], "leaf_value": []}
    return [({k: v.tolist() for k, v in tabs[c][a].items()} if c in tabs and c in keep else dict(empty))
            | {"inputs": list(range(THREE_POSITION_INPUTS))} for c in range(4) for a in (0, 1)]


def twin_c(t: dict) -> str:
    """The site map (impactsense_twin_map) and twin configuration (impactsense_twin) as C."""
    g = t["grid"]
    vec = lambda a: "{" + ", ".join(_c_float(v) for v in np.asarray(a).tolist()) + "}"  # noqa: E731
    grid = f"{int(g[0])}, {int(g[1])}, {_c_float(g[2])}, {_c_float(g[3])}, {_c_float(g[4])}"
    site = ",\n  ".join([grid, vec(t["base"]), vec(t["scale"]), "twin_q"])
    cfg = ",\n  ".join([vec(t["offset"]), vec(t["slope"]), vec(t["weight"]),
                        ", ".join(_c_float(v) for v in t["config"].tolist()),
                        ", ".join(_c_float(v) for v in t["uncertainty"].tolist()),
                        ", ".join(_c_float(v) for v in np.asarray(t.get("edge", np.zeros(4)), np.float32).tolist())])
    return (_c_array("uint8_t", "twin_q", t["q"], str)
            + f"const impactsense_site_map impactsense_twin_map = {{\n  {site}\n}};\n"
            + f"const impactsense_twin_config impactsense_twin = {{\n  {cfg}\n}};\n\n")


# --- m2cgen, one function per tree, float32 ---

_THRESH = re.compile(r"(input\[\d+\]\s*(?:<=|<|>=|>)\s*)([-+0-9.eE]+)")
_NUMBER = re.compile(r"(?<![\w\[.])([-+]?\d+\.\d*(?:[eE][-+]?\d+)?|[-+]?\d+[eE][-+]?\d+)(?![\w\]])")
_BINARY_LEAF = re.compile(r"memcpy\(var0, \(double\[\]\)\{([^,}]+), ([^}]+)\}, 2 \* sizeof\(double\)\);")


def m2cgen_tree_c(tree, name: str, classifier: bool) -> str:
    """m2cgen's C for one tree, rewritten to `float name(const float* input)` in float32."""
    import m2cgen

    code = m2cgen.export_to_c(tree, function_name=name)
    code = code.replace("#include <string.h>\n", "")
    if classifier:
        # Binary classifier: keep P(class 1) as the tree's value.
        code = _BINARY_LEAF.sub(lambda m: f"var0 = {m.group(2).strip()};", code)
        code = code.replace("double var0[2];", "double var0;")
        code = code.replace("void " + name + "(double * input, double * output)",
                            "float " + name + "(const float * input)")
        code = code.replace("memcpy(output, var0, 2 * sizeof(double));", "return var0;")
    else:
        code = code.replace("double " + name + "(double * input)", "float " + name + "(const float * input)")
    if "memcpy" in code or "(double * input" in code:
        raise ExportError("unexpected m2cgen output; cannot post-process")
    code = _THRESH.sub(lambda m: m.group(1) + _c_float(f32_floor(float(m.group(2)))), code)
    code = _NUMBER.sub(lambda m: _c_float(float(m.group(1))), code)
    code = code.replace("double", "float")
    return "static " + code.strip() + "\n"


def m2cgen_c(models: ModelSet, n_trees: dict[str, int], header: str) -> str:
    out = [header, '#include "impactsense_models.h"\n\n']
    for role, forest in (("x", models.x), ("y", models.y), ("energy", models.energy)):
        classifier = role == "energy"
        if classifier and models.energy_linear:
            out.append(linear_c(forest, f"impactsense_m2c_{role}") + "\n")
            continue
        k = n_trees[role]
        names = []
        for i, est in enumerate(forest.estimators_[:k]):
            name = f"{role}_tree_{i}"
            out.append(m2cgen_tree_c(est, name, classifier))
            names.append(name)
        out.append(f"float impactsense_m2c_{role}(const float* input) {{\n  float s = 0.0f;\n")
        out.extend(f"  s += {n}(input);\n" for n in names)
        out.append(f"  return s / {float(k):.1f}f;\n}}\n\n")
    return "".join(out)


# The header's line for a model whose energy class is the linear estimate (impactapp_models.h: linear_terms over
# the energy arrays); absent for a classifier forest, so a forest model's header is as before.
LINEAR_DEFINE = "#define IMPACTSENSE_ENERGY_LINEAR 1             // the energy arrays: a linear estimate (impactapp::linear_terms)\n"

# A model without a twin that keeps the three-channel classes (height_class.fit_three_channel_classes): the header's
# define and declaration (absent otherwise, so another model's header is as before).
THREE_CHANNEL_INPUTS = 7   # impactcore kThreeChannelInputs (height_class.LINEAR_CLASS_FEATURES)
THREE_CHANNEL_DEFINE = ("#define IMPACTSENSE_THREE_CHANNEL_CLASS 1      // per channel the class of a drop without it "
                        "(impactapp TableModels' three_channel)\n")
THREE_CHANNEL_DECL = ("// Per channel c the energy class of a drop without c (linear, on impactcore::three_channel_inputs).\n"
                      "extern const impactsense_model impactsense_model_energy_without[4];\n")

# A model without a twin that keeps the three-sensor position's pairs (board.models.board_three_positions).
THREE_POSITION_INPUTS = 11   # impactcore kThreePositionInputs (three_channel_position.N_INPUTS)
THREE_POSITION_DEFINE = ("#define IMPACTSENSE_THREE_POSITION 1      // per channel the pair correcting the three-sensor "
                         "position without it (impactapp TableModels' three_position)\n")
THREE_POSITION_DECL = ("// Per channel c the x (2c) and y (2c + 1) corrections of the three-sensor position without c (boosted\n"
                       "// trees on impactcore::three_position_inputs; 0 trees: none).\n"
                       "extern const impactsense_model impactsense_model_position_without[8];\n")

def trigger_define(signal: dict) -> str:
    """The header's line for the trigger threshold export chose (the signal's board.capture.TRIGGER_KEY, board
    counts; impactapp::exported_config applies it at boot); absent when the firmware's default stands, so the
    header is as before."""
    value = signal.get("trigger_counts")
    if value is None:
        return ""
    return (f"#define IMPACTSENSE_TRIGGER_COUNTS {_c_float(float(value))}  // the board's trigger threshold, "
            "board counts (chosen from the model's drops)\n")


HEADER_H = """// Generated by `impactsense export`; do not edit. Model card {model_hash}
#pragma once
#include <stdint.h>

#define IMPACTSENSE_N_FEATURES {n_features}  // length of impactcore's feature vector
#define IMPACTSENSE_RESIDUAL_XY {residual}    // 1: x, y forests predict corrections to the physics position
#define IMPACTSENSE_TWIN {twin}               // 1: the energy classifier reads the twin's height estimate
#define IMPACTSENSE_TWIN_INPUT IMPACTSENSE_N_FEATURES  // that input's index (impactapp::kTwinInput)
#define IMPACTSENSE_TWIN_FEATURES 16          // the twin's per-event features (impactcore::kTwinFeatures)
#define IMPACTSENSE_TWIN_EDGE 1               // the twin config carries the height estimate's edge term
{energy_linear}
#ifdef __cplusplus
extern "C" {{
#endif

// Node tables (impactsense_forest_tables.c): impactapp::ForestTables' arrays (forest.h). Split nodes and leaves
// apart, each in preorder; tree t's split nodes roots[t] .. roots[t + 1] - 1, its leaves from roots[t] + t.
typedef struct {{
  int32_t n_trees;
  const int32_t* roots;
  const uint8_t* feature;      // split node: the input it reads
  const int32_t* threshold;    // split node: the float32 threshold's order key (left when input <= threshold)
  const uint16_t* skip;        // split node: the leaves under its left child
  const uint16_t* leaf;        // leaf: index into leaf_value
  const float* leaf_value;     // the forest's distinct leaf values
  const float* value;          // a linear model's terms (the forest arrays then null)
}} impactsense_forest;

// A forest and the indices of the feature-vector entries it reads (in training order).
typedef struct {{
  impactsense_forest forest;
  const uint8_t* inputs;
  int32_t n_inputs;
}} impactsense_model;
extern const impactsense_model impactsense_model_x;
extern const impactsense_model impactsense_model_y;
extern const impactsense_model impactsense_model_energy;  // leaf value = P(high energy)
{three_channel_decl}
// The twin's site map and configuration (impactcore::SiteMap / TwinConfig, twin.h): feature k of grid point
// (i, j) = base[k] + scale[k] * q[(i * ny + j) * 16 + k]; q = 255 where no drop (a sensor disc).
typedef struct {{
  int32_t nx, ny;
  float x0_mm, y0_mm, step_mm;
  float base[IMPACTSENSE_TWIN_FEATURES];
  float scale[IMPACTSENSE_TWIN_FEATURES];
  const uint8_t* q;
}} impactsense_site_map;
typedef struct {{
  float offset[IMPACTSENSE_TWIN_FEATURES];
  float slope[IMPACTSENSE_TWIN_FEATURES];
  float weight[IMPACTSENSE_TWIN_FEATURES];
  float ref_log10_height_mm, prior_mm, cutoff_mm, temperature, coarse_cutoff_mm, weak_channel;
  // The reported 1-sigma radial uncertainty (mm): (offset + scale * spread) * sqrt(max(1, misfit / misfit_ref))
  float uncertainty_offset_mm, uncertainty_scale, uncertainty_misfit_ref;
  // The height estimate's edge term: log10 h -= edge_log10_bias * max(0, 1 - d / edge_ramp_mm), d the reported
  // position's distance to the nearest edge of the plate_x_mm x plate_y_mm plate (ramp 0: none)
  float edge_log10_bias, edge_ramp_mm, plate_x_mm, plate_y_mm;
}} impactsense_twin_config;
#if IMPACTSENSE_TWIN
extern const impactsense_site_map impactsense_twin_map;
extern const impactsense_twin_config impactsense_twin;
#endif

// The model card's signal and localiser settings (impactcore.h's CoreConfig and LocaliserConfig fields but
// the ADC rails; sample counts at fs_hz, the training rate; the role says how impactapp::exported_config
// takes each one to the board's rate).
{signal_struct}extern const impactsense_signal_config impactsense_signal;

// m2cgen, one function per tree, float32 (impactsense_models_m2c.c): the forest means of the gathered
// inputs (input[k] = feature_vector[model.inputs[k]], or the twin's estimate for IMPACTSENSE_TWIN_INPUT).
float impactsense_m2c_x(const float* input);
float impactsense_m2c_y(const float* input);
float impactsense_m2c_energy(const float* input);  // P(high energy); class 1 when > 0.5

#ifdef __cplusplus
}}
#endif
"""
