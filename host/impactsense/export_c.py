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

LEAF = 0xFF


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


def forest_tables(forest, n_trees: int | None = None) -> dict:
    """Node tables of the first n_trees trees of a fitted forest (see module doc)."""
    classifier = hasattr(forest, "predict_proba")
    trees = forest.estimators_[: n_trees or len(forest.estimators_)]
    roots, feature, value, right = [], [], [], []
    for est in trees:
        t = est.tree_
        n = t.node_count
        if n > 0xFFFF:
            raise ExportError(f"a tree of {n} nodes exceeds the u16 child index")
        leaf = t.children_left == -1
        internal = np.flatnonzero(~leaf)
        if np.any(t.children_left[internal] != internal + 1):
            raise ExportError("tree is not in depth-first order (left child != next node)")
        if np.any(t.feature[internal] >= LEAF):
            raise ExportError("more than 254 features")
        roots.append(len(feature))
        f = np.where(leaf, LEAF, t.feature).astype(np.uint8)
        vals = np.where(leaf, _leaf_values(t, classifier).astype(np.float32), f32_floor(t.threshold))
        r = np.where(leaf, 0, t.children_right).astype(np.uint16)
        feature.extend(f.tolist())
        value.extend(vals.astype(np.float32).tolist())
        right.extend(r.tolist())
    return {
        "roots": np.asarray(roots, dtype=np.int32),
        "feature": np.asarray(feature, dtype=np.uint8),
        "value": np.asarray(value, dtype=np.float32),
        "right": np.asarray(right, dtype=np.uint16),
    }


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


def tables_c(tabs: dict[str, dict], models, header: str) -> str:
    out = [header, '#include "impactsense_models.h"\n\n']
    for role, t in tabs.items():
        # The m2cgen build (IMPACTSENSE_MODELS_M2CGEN) keeps the inputs and drops the node tables.
        out.append("#ifndef IMPACTSENSE_MODELS_M2CGEN\n")
        out.append(_c_array("int32_t", f"{role}_roots", t["roots"], str))
        out.append(_c_array("uint8_t", f"{role}_feature", t["feature"], str))
        out.append(_c_array("float", f"{role}_value", t["value"], _c_float))
        out.append(_c_array("uint16_t", f"{role}_right", t["right"], str))
        out.append(_c_array("uint8_t", f"{role}_inputs", models.inputs[role], str))
        out.append(f"const impactsense_model impactsense_model_{role} = {{{{{len(t['roots'])}, {role}_roots, "
                   f"{role}_feature, {role}_value, {role}_right}}, {role}_inputs, {len(models.inputs[role])}}};\n")
        out.append("#else\n")
        out.append(_c_array("uint8_t", f"{role}_inputs", models.inputs[role], str))
        out.append(f"const impactsense_model impactsense_model_{role} = {{{{0, 0, 0, 0, 0}}, {role}_inputs, "
                   f"{len(models.inputs[role])}}};\n#endif\n\n")
    if models.twin is not None:
        out.append(twin_c(models.twin))
    if models.three_channel:
        out.append(three_channel_c({c: linear_tables(m) for c, m in models.three_channel.items()}))
    out.append(signal_c(models.signal))
    return "".join(out)


def three_channel_c(tabs: dict) -> str:
    """The three-channel classes (height_class.linear_tables of each channel left out) as
    impactsense_model_energy_without[4], in both builds (the m2cgen one runs them as tables too)."""
    out, models = [], []
    for c in range(4):
        t = tabs[c]
        out.append(_c_array("int32_t", f"without_{c}_roots", t["roots"], str))
        out.append(_c_array("uint8_t", f"without_{c}_feature", t["feature"], str))
        out.append(_c_array("float", f"without_{c}_value", t["value"], _c_float))
        out.append(_c_array("uint16_t", f"without_{c}_right", t["right"], str))
        models.append(f"{{{{{len(t['roots'])}, without_{c}_roots, without_{c}_feature, without_{c}_value, "
                      f"without_{c}_right}}, 0, {THREE_CHANNEL_INPUTS}}}")
    out.append("const impactsense_model impactsense_model_energy_without[4] = {\n  " + ",\n  ".join(models)
               + "\n};\n\n")
    return "".join(out)


def twin_c(t: dict) -> str:
    """The site map (impactsense_twin_map) and twin configuration (impactsense_twin) as C."""
    g = t["grid"]
    vec = lambda a: "{" + ", ".join(_c_float(v) for v in np.asarray(a).tolist()) + "}"  # noqa: E731
    grid = f"{int(g[0])}, {int(g[1])}, {_c_float(g[2])}, {_c_float(g[3])}, {_c_float(g[4])}"
    site = ",\n  ".join([grid, vec(t["base"]), vec(t["scale"]), "twin_q"])
    cfg = ",\n  ".join([vec(t["offset"]), vec(t["slope"]), vec(t["weight"]),
                        ", ".join(_c_float(v) for v in t["config"].tolist()),
                        ", ".join(_c_float(v) for v in t["uncertainty"].tolist())])
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

HEADER_H = """// Generated by `impactsense export`; do not edit. Model card {model_hash}
#pragma once
#include <stdint.h>

#define IMPACTSENSE_N_FEATURES {n_features}  // length of impactcore's feature vector
#define IMPACTSENSE_RESIDUAL_XY {residual}    // 1: x, y forests predict corrections to the physics position
#define IMPACTSENSE_TWIN {twin}               // 1: the energy classifier reads the twin's height estimate
#define IMPACTSENSE_TWIN_INPUT IMPACTSENSE_N_FEATURES  // that input's index (impactapp::kTwinInput)
#define IMPACTSENSE_TWIN_FEATURES 16          // the twin's per-event features (impactcore::kTwinFeatures)
{energy_linear}
#ifdef __cplusplus
extern "C" {{
#endif

// Node tables (impactsense_forest_tables.c): same layout as impactapp::ForestTables.
typedef struct {{
  int32_t n_trees;
  const int32_t* roots;
  const uint8_t* feature;
  const float* value;
  const uint16_t* right;
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
