"""Model export for the firmware: scikit-learn forests -> C the Cortex-M4F runs in float32.

With `export_c` (the C text), the only modules that know about scikit-learn's tree internals and m2cgen. Two
forms, both written:

- **Node tables** (`impactsense_forest_tables.c`, emlearn style, the firmware default): a forest is data —
  split nodes and leaves apart, each in preorder: per split node a feature index with two child-is-a-leaf
  bits (u8), a float32 threshold and the leaves under its left child (u16; 7 bytes), per leaf the index of
  its value among the forest's distinct leaf values (u16, and f32 per distinct value: the values exactly);
  walked by `impactapp::forest_mean` (firmware/lib/impactapp, forest.h). The same tables go to `forest_tables.npz`
  for the emulator, so the emulator runs the very numbers the board runs.
- **The twin's site map** (models trained with one, `impactsense train --site-map`): the uint8 table, its
  base/scale and grid, and the model card's twin configuration, in `impactsense_forest_tables.c` and
  `forest_tables.npz`; the energy classifier then reads one input, index IMPACTSENSE_N_FEATURES (the
  firmware's `impactapp::kTwinInput`): the twin's log10 height estimate at the forests' position
  (impactcore twin.h, the same C++ the host trains with); the board reports the twin's matched position
  there, as models.ImpactModel.predict does, and `--trees auto` picks the prefix on that position's error.
- **m2cgen** (`impactsense_models_m2c.c`): m2cgen per tree (one function per tree, so no function grows past
  the Thumb-2 branch range), post-processed to float32 (the M4F emulates `double` in software).

Thresholds are scikit-learn's float64 split points rounded *down* to float32: for float32 inputs
`x <= t32` decides exactly as scikit-learn's `float64(x) <= t`, so the C gives the Python predictions to
float32 rounding of the leaf sums.
"""

from __future__ import annotations

import hashlib
import json
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import DataError, ImpactSenseError
from .export_c import (HEADER_H, LEAF, LINEAR_DEFINE, THREE_CHANNEL_DECL, THREE_CHANNEL_DEFINE,  # noqa: F401
                       TABLE_KEYS, ExportError, _c_float, exported_fields,
                       f32_floor, forest_tables, table_nodes, m2cgen_c, signal_c, signal_struct_c, table_bytes, tables_c)
from . import export_c, export_check
from .height_class import linear_tables
from .host_columns import HOST_LOCATION_FEATURES
from .outputs import json_text, output_folder


@dataclass
class ModelSet:
    """One regressor per coordinate and a binary energy classifier (scikit-learn forests), with the indices
    of the core's feature vector each one reads and whether x/y are corrections to the physics position."""

    x: object
    y: object
    energy: object
    card: dict
    n_features: int                 # length of the core's feature vector
    inputs: dict                    # role -> list of feature indices
    residual_xy: bool
    signal: dict
    twin: dict | None = None        # the site map and twin configuration (twin_arrays), when the card has one
    # without a twin: channel -> the energy class of a drop without that channel (height_class.LinearHeightClass)
    three_channel: dict = field(default_factory=dict)
    # the channel check as the board runs it (export_check.check_arrays), or None
    channel_check: dict | None = None
    check_note: str | None = None   # why the board does not get the card's check (export_check.budgeted)
    four_channel_note: str | None = None   # why the board does not get the card's four-channel choice (export_check)
    three_position: dict = field(default_factory=dict)   # channel -> its pair (three_channel_position.load_board_pairs)

    def three_channel_tables(self) -> dict:
        """channel -> the three-channel class's arrays (height_class.linear_tables); {} without them."""
        return {c: linear_tables(m) for c, m in sorted(self.three_channel.items())}

    @property
    def energy_linear(self) -> bool:
        """The energy class is the linear estimate of log m g h (height_class.LinearHeightClass), not a forest."""
        return not hasattr(self.energy, "estimators_")

    def energy_tables(self, n_trees: int | None = None) -> dict:
        """The energy model's node-table arrays: a forest prefix's, or the linear model's (linear_tables)."""
        return linear_tables(self.energy) if self.energy_linear else forest_tables(self.energy, n_trees)

    def energy_trees(self) -> int:
        """The energy forest's trees (a linear model: its terms, the tables' n_trees)."""
        return len(self.energy.terms) if self.energy_linear else len(self.energy.estimators_)


def twin_arrays(site, fit, plate_mm: tuple[float, float] = (0.0, 0.0)) -> dict:
    """The twin's site map (sitemap.SiteMap) and fit (twin.TwinFit) as the firmware's arrays: grid [nx, ny,
    x0_mm, y0_mm, step_mm], q uint8 [nx * ny * 16], base, scale, offset, slope, weight float32 [16],
    config [ref_log10_height_mm, prior_mm, cutoff_mm, temperature, coarse_cutoff_mm, weak_channel] and uncertainty
    [offset_mm, scale, misfit_ref] (the reported 1-sigma: twin.calibrated_uncertainty), edge [bias, ramp_mm,
    plate_x_mm, plate_y_mm] (the height estimate's edge term, twin_edge.py; plate_mm the model's plate)."""
    f32 = lambda v: np.asarray(v, dtype=np.float32)  # noqa: E731
    return {"grid": f32([site.nx, site.ny, site.x0_mm, site.y0_mm, site.step_mm]),
            "q": np.ascontiguousarray(site.q, dtype=np.uint8).reshape(-1),
            "base": f32(site.base), "scale": f32(site.scale), "offset": f32(fit.offset), "slope": f32(fit.slope),
            "weight": f32(fit.weight),
            "config": f32([fit.ref_log10_height_mm, fit.prior_mm, fit.cutoff_mm, fit.temperature,
                           fit.coarse_cutoff_mm, fit.weak_channel]),
            "uncertainty": f32([fit.uncertainty_offset_mm, fit.uncertainty_scale, fit.uncertainty_misfit_ref]),
            "edge": f32([fit.edge_log10_bias, fit.edge_ramp_mm, plate_mm[0], plate_mm[1]])}


def _load_twin(model_dir: Path, card: dict, card_path: Path) -> dict:
    from .models import SITE_MAP_FILE
    from .sitemap import SiteMap
    from .twin import TwinFit

    from .modelfolder import verified_path

    t = card["twin"]
    try:
        if not isinstance(t, dict):
            raise DataError(card_path, "twin", "must be an object")
        site = SiteMap.load(verified_path(model_dir, card, card_path, t.get("site_map", SITE_MAP_FILE), "twin.site_map"))
        fit = TwinFit.from_dict({k: v for k, v in t.items() if k not in ("site_map", "site_map_sha", "ref_height_mm")})
    except DataError as exc:
        raise ExportError(f"{card_path} [twin]: {exc}") from None
    if t.get("site_map_sha") and site.fingerprint() != t["site_map_sha"]:
        raise ExportError(f"{card_path} [twin.site_map_sha]: the site map differs from the one the model was trained with")
    signal = card.get("signal") if isinstance(card.get("signal"), dict) else {}
    plate = (float(signal.get("plate_x_mm", 0.0) or 0.0), float(signal.get("plate_y_mm", 0.0) or 0.0))
    if fit.edge_ramp_mm > 0 and not (plate[0] > 0 and plate[1] > 0):
        raise ExportError(f"{card_path} [signal.plate_x_mm / plate_y_mm]: the twin's edge term needs the plate's size")
    return twin_arrays(site, fit, plate)


def beyond_the_board(card: dict) -> tuple[str, str] | None:
    """(card field, why) when a model uses what the board cannot run as it is (then `export` trains the board's
    own models, even at the board's own rate), else None."""
    if card.get("position_members"):
        return "position_members", "the board runs one forest pair on the physics position"
    if set(card.get("location_features") or []) & set(HOST_LOCATION_FEATURES):
        return "location_features", "the board's forests read the core's feature vector only (host_columns.py)"
    signal = card.get("signal") if isinstance(card.get("signal"), dict) else {}
    if int(signal.get("posterior_grid", 0) or 0) > 1:
        return "signal.posterior_grid", "the localiser's posterior mean costs more than the board's event budget"
    return None


def needs_board_refit(card: dict, rate: int | None) -> bool:
    """Whether `export` at board rate `rate` (None: --rate native) trains the board's own models: the model was
    trained at another rate, or uses what the board cannot run (beyond_the_board)."""
    if rate is None:
        return False
    trained_at = int(card.get("board_fs_hz") or card.get("signal", {}).get("fs_hz") or 0)
    return trained_at != int(rate) or beyond_the_board(card) is not None


def load_models(model_dir) -> ModelSet:
    """The forests and settings of a model folder, read through modelfolder.py (named files only, checksums
    checked, no pickles); problems are ExportErrors naming the file and field."""
    from .modelfolder import load_forests, read_card

    model_dir = Path(model_dir)
    try:
        card, card_path = read_card(model_dir)
        roles = {r: card["files"].get(r) for r in ("x", "y", "energy")}
        models = load_forests(model_dir, card, card_path, ("x", "y", "energy"))
    except DataError as exc:
        raise ExportError(str(exc)) from None
    beyond = beyond_the_board(card)
    if beyond is not None:
        raise ExportError(f"{card_path} [{beyond[0]}]: {beyond[1]}; export it without --rate native: that trains "
                          f"the board's own models (at the board's rate, on the same drops)")
    for role in ("x", "y"):
        if not hasattr(models[role], "estimators_") or getattr(models[role], "n_outputs_", 1) != 1:
            raise ExportError(f"{roles[role]}: need a single-output random forest regressor")
    if len(getattr(models["energy"], "classes_", [])) != 2:
        raise ExportError(f"{roles['energy']}: the energy classifier must have two classes")
    names = card.get("feature_names")
    for key, want in (("feature_names", list), ("location_features", list), ("energy_features", list),
                      ("signal", dict), ("twin", dict)):
        if card.get(key) is not None and not isinstance(card[key], want):
            raise ExportError(f"{card_path} [{key}]: must be a JSON {'list' if want is list else 'object'}")
    n = len(names) if names else int(models["x"].n_features_in_)
    twin = _load_twin(model_dir, card, card_path) if "twin" in card else None
    inputs = {}
    for role, key in (("x", "location_features"), ("y", "location_features"), ("energy", "energy_features")):
        sel = card.get(key)
        if role == "energy" and twin is not None:
            # The twin's height estimate: one input past the core's feature vector (impactapp::kTwinInput).
            if sel != ["twin_log10_height_mm"]:
                raise ExportError(f"{card_path} [energy_features]: a twin model's classifier reads "
                                  f"['twin_log10_height_mm'], the card lists {sel}")
            idx = [n]
        else:
            try:
                idx = ([names.index(f) for f in sel] if sel and names else
                       list(range(int(models[role].n_features_in_))))
            except (ValueError, TypeError, AttributeError):
                raise ExportError(f"{card_path} [{key}]: names a feature not in feature_names") from None
        if len(idx) != models[role].n_features_in_:
            raise ExportError(f"{card_path}: {key} lists {len(idx)} features, the {role} forest reads "
                              f"{models[role].n_features_in_}")
        if max(idx) > n or (max(idx) == n and twin is None) or n >= 255:
            raise ExportError(f"{card_path}: feature index out of range")
        inputs[role] = idx
    residual = "phys_x_mm +" in str(card.get("target", ""))
    three, pairs = _load_three_channel(model_dir, card, card_path) if twin is None else ({}, {})
    from .board.capture import board_signal   # with the trigger threshold a board model chose (board.trigger)
    signal = board_signal(card)
    return ModelSet(models["x"], models["y"], models["energy"], card, n, inputs, residual, signal, twin, three,
                    export_check.check_arrays(card, signal, bool(three), card_path), three_position=pairs)


def _load_three_channel(model_dir: Path, card: dict, card_path: Path) -> tuple[dict, dict]:
    """(the card's three-channel classes, all four channels or none; with them the board's pairs, load_board_pairs)."""
    from .height_class import LINEAR_CLASS_FEATURES, LinearHeightClass
    from .modelfolder import read_verified
    from .three_channel_position import load_board_pairs

    three = card.get("three_channel_class") or {}
    if not isinstance(three, dict) or sorted(three) != ["0", "1", "2", "3"]:
        return {}, {}
    out = {}
    try:
        for c, name in three.items():
            path, data = read_verified(model_dir, card, card_path, name, f"three_channel_class.{c}")
            out[int(c)] = LinearHeightClass.load(path, data)
            if out[int(c)].n_features_in_ != len(LINEAR_CLASS_FEATURES):
                raise DataError(path, None, f"reads {out[int(c)].n_features_in_} inputs, not {len(LINEAR_CLASS_FEATURES)}")
        return out, load_board_pairs(model_dir, card, card_path)
    except DataError as exc:
        raise ExportError(str(exc)) from None


def twin_xy(twin: dict, feats: np.ndarray, usable: np.ndarray, xy_mm: np.ndarray) -> np.ndarray:
    """The twin's matched position (the core's twin_estimate, as the board runs it from the exported arrays
    `twin`) around xy_mm [R, 2] for the events' twin features [R, 16] / usable masks [R]; NaN where it fails."""
    from . import _core

    f32 = lambda a: np.ascontiguousarray(np.asarray(a, np.float32))  # noqa: E731
    nx, ny, x0, y0, step = (float(v) for v in twin["grid"])
    ref, prior, cutoff, temp, coarse = ([float(v) for v in twin["config"]] + [0.0])[:5]  # older exports: 4
    r = _core.twin_estimate_batch(f32(feats), np.ascontiguousarray(usable, np.uint16), f32(xy_mm),
                                  np.ascontiguousarray(twin["q"], np.uint8).reshape(-1, 16), int(nx), int(ny), x0,
                                  y0, step, f32(twin["base"]), f32(twin["scale"]), f32(twin["offset"]),
                                  f32(twin["slope"]), f32(twin["weight"]), ref, prior, cutoff, temp, coarse)
    out = np.asarray(r["xy_mm"], float)
    out[np.asarray(r["status"]) != 0] = np.nan
    return out


# The per-event cycle budget (issue 6: <= 64,000 instructions, 1 ms at 64 MHz) bounds the localisation forests of
# a twin model: with 15 trees per coordinate every bundled drop fits (the margin, measured by
# `python3 benchmarks/bench_firmware_cost.py --all --trees N` in qemu: docs/findings.md, "Numbers from the
# code's docstrings").
TWIN_MAX_TREES = 15

# The flash budget (issue 17) is for the project's code and models together: the models get what the firmware's
# own code (firmware/src + firmware/lib, text+data as `scripts/board-build.sh` reports it, with room to grow:
# its size is in docs/findings.md; 88 KB allowed; tests/test_board_build.py holds the real code to it) leaves of
# 256 KB.
FLASH_BUDGET_BYTES = 256 * 1024
FIRMWARE_CODE_BYTES = 88 * 1024
MODELS_FLASH_BUDGET = FLASH_BUDGET_BYTES - FIRMWARE_CODE_BYTES


def select_trees(models: ModelSet, vector: np.ndarray | None, phys_xy: np.ndarray | None, xy: np.ndarray | None,
                 tol_mm: float = 0.2, budget_bytes: int = MODELS_FLASH_BUDGET, twin_eval=None,
                 max_trees: int | None = None, max_instructions: int | None = None) -> tuple[int, list[dict]]:
    """Trees per coordinate forest: the smallest prefix within tol_mm mean distance (of the reported position from
    the truth) of the full forests on the held-out
    drops (vector: the core's feature vectors, usable rows only), shrunk further if the tables would
    exceed the flash budget or the prefix would exceed max_trees (the cycle budget's bound). A prefix of a
    random forest is itself a random forest. With the twin (and twin_eval = (twin features [R, 16], usable
    masks [R]) of the same drops) the distance is the reported position's: the twin's match around each prefix's
    position (mean_distance_mm; the forests' own: forest_mean_distance_mm). max_instructions: what the event
    budget leaves the forests (board.cost): the energy forest then takes the same prefix as the coordinates'
    (energy_trees) and a row fits when the forests' estimated cost, each tree walked to its deepest leaf
    (instructions), is within it. Each row says whether it fits the budgets."""
    n_all = len(models.x.estimators_)
    if vector is None or len(vector) == 0:
        return n_all, []
    X = np.asarray(vector, dtype=np.float32)
    base = np.asarray(phys_xy, float) if models.residual_xy else np.zeros((len(X), 2))
    px = np.stack([t.predict(X[:, models.inputs["x"]]) for t in models.x.estimators_])
    py = np.stack([t.predict(X[:, models.inputs["y"]]) for t in models.y.estimators_])
    n_energy = models.energy_trees()
    e_bytes = table_bytes(models.energy_tables()) + table_bytes(models.twin)
    nodes = None
    sizes = (5, 10, 15, 20, 25, 30, 40, 50, 75, 100, 150, 200, n_all)
    if max_instructions is not None:
        from .board.cost import deepest_walks
        nodes = {r: deepest_walks(f) for r, f in (("x", models.x), ("y", models.y), ("energy", models.energy))
                 if r != "energy" or not models.energy_linear}
        sizes = (1, 2, 3, 4, *sizes)
    # the board's boosted trees (board.boosted): every tree is the model, no prefix is; the energy forest's prefix is
    # what the sweep chooses then (the whole boosted pair with each)
    boosted = bool((models.card.get("board_forests") or {}).get("use_boosted"))
    rows = []
    for k in sorted({k for k in sizes if k <= (n_energy if boosted and nodes is not None else n_all)}):
        kxy = n_all if boosted else k
        pos = base + np.c_[px[:kxy].mean(0), py[:kxy].mean(0)]
        if nodes is not None:
            e_bytes = table_bytes(models.energy_tables(min(k, n_energy))) + table_bytes(models.twin)
        b = table_bytes(forest_tables(models.x, kxy)) + table_bytes(forest_tables(models.y, kxy)) + e_bytes
        row = {"trees": k, "mean_distance_mm": float(np.mean(np.hypot(*(pos - xy).T))), "table_bytes": b}
        if models.twin is not None and twin_eval is not None:
            tw = twin_xy(models.twin, *twin_eval, pos)
            ok = np.isfinite(tw).all(1)
            row.update(forest_mean_distance_mm=row["mean_distance_mm"],
                       mean_distance_mm=float(np.mean(np.hypot(*(tw[ok] - xy[ok]).T))))
        row["within_budgets"] = b <= budget_bytes and (max_trees is None or k <= max_trees)
        if nodes is not None:
            from .board.cost import forests_instructions, linear_instructions
            row["energy_trees"] = n_energy if models.energy_linear else min(k, n_energy)
            n_inputs = {r: len(v) for r, v in models.inputs.items()}
            row["instructions"] = (forests_instructions(nodes, {"x": kxy, "y": kxy}, n_inputs)
                                   + linear_instructions(n_energy) if models.energy_linear else
                                   forests_instructions(nodes, {"x": kxy, "y": kxy, "energy": row["energy_trees"]},
                                                        n_inputs))
            row["within_budgets"] = row["within_budgets"] and row["instructions"] <= max_instructions
        rows.append(row)
    if boosted:
        row = ([r for r in rows if r["within_budgets"]] or rows[:1])[-1]
        return n_all, [{**r, "trees": n_all} for r in rows if r is row]
    best = min(r["mean_distance_mm"] for r in rows)
    chosen = min(r["trees"] for r in rows if r["mean_distance_mm"] <= best + tol_mm)
    fits = [r["trees"] for r in rows if r["within_budgets"]]
    if fits and chosen > max(fits):
        chosen = max(fits)
    elif not fits and nodes is not None:   # nothing within the event budget: the cheapest forests
        chosen = min(r["trees"] for r in rows)
    return chosen, rows


@contextmanager
def staged_output(out_dir, force: bool = False):
    """outputs.output_folder for an export: a fresh folder next to out_dir that becomes out_dir when the block
    ends normally; when it raises, out_dir is as it was. Errors other than the package's own come out as an
    ExportError saying so."""
    out = Path(out_dir)
    try:
        with output_folder(out, force, tool="impactsense export") as stage:
            yield stage
    except ImpactSenseError:
        raise
    except Exception as exc:
        raise ExportError(f"{out}: export failed ({type(exc).__name__}: {exc}); nothing was written, "
                          f"{out} is as it was") from exc


def export_models(model_dir, out_dir, trees: str | int = "all", X_eval=None, xy_eval=None,
                  write_m2cgen: bool = True, phys_eval=None, twin_eval=None, into_stage: bool = False,
                  energy_trees: int | None = None) -> dict:
    """Writes the C sources, the emulator's tables and export.json into out_dir (all of them or, on an error,
    none: staged_output); returns the summary. energy_trees: the energy forest's prefix with a number of trees
    (default: whole; with trees auto the event budget may choose one)."""
    models = load_models(model_dir)
    if into_stage:      # out_dir is already a staging folder (outputs.output_folder) the caller commits
        return _write_export(models, model_dir, Path(out_dir), trees, X_eval, xy_eval, write_m2cgen, phys_eval,
                             twin_eval, energy_trees)
    with staged_output(out_dir) as stage:
        return _write_export(models, model_dir, stage, trees, X_eval, xy_eval, write_m2cgen, phys_eval, twin_eval,
                             energy_trees)


def header_h(models: ModelSet, model_hash: str) -> str:
    """impactsense_models.h: the defines and declarations of what this model has (a forest model's as before)."""
    pos_define, pos_decl = export_c.three_position_header(models)
    defines = ((LINEAR_DEFINE if models.energy_linear else "") + (THREE_CHANNEL_DEFINE if models.three_channel else "")
               + (export_check.CHECK_DEFINE if models.channel_check else "") + pos_define)
    decls = ((THREE_CHANNEL_DECL if models.three_channel else "")
             + (export_check.CHECK_DECL if models.channel_check else "") + pos_decl)
    return HEADER_H.format(model_hash=model_hash, n_features=models.n_features, signal_struct=signal_struct_c(),
                           residual=int(models.residual_xy), twin=int(models.twin is not None),
                           energy_linear=defines + export_c.trigger_define(models.signal), three_channel_decl=decls)


def _write_export(models, model_dir, out_dir: Path, trees, X_eval, xy_eval, write_m2cgen, phys_eval,
                  twin_eval, energy_trees: int | None = None) -> dict:
    card_bytes = (Path(model_dir) / "model_card.json").read_bytes()
    model_hash = hashlib.sha256(card_bytes).hexdigest()[:16]
    sweep = []
    n_energy = (models.energy_trees() if energy_trees is None or models.energy_linear
                else min(int(energy_trees), models.energy_trees()))
    signal_cost = None
    if trees == "auto":
        # a model without the twin: its forests get what the event budget leaves after the signal's options
        # (board.cost; a twin model's forests are capped at TWIN_MAX_TREES, measured with the twin's match)
        from .board.cost import EVENT_BUDGET
        signal_cost = export_check.board_signal_cost(models)
        k, sweep = select_trees(models, X_eval, phys_eval, xy_eval, twin_eval=twin_eval,
                                max_trees=TWIN_MAX_TREES if models.twin is not None else None,
                                max_instructions=None if signal_cost is None else EVENT_BUDGET - signal_cost["total"])
        row = next((r for r in sweep if r["trees"] == k), {})
        n_energy = row.get("energy_trees", n_energy)
        export_check.four_channel_within(models, signal_cost, row.get("instructions"))
    elif trees == "all" or (models.card.get("board_forests") or {}).get("use_boosted"):
        k = len(models.x.estimators_)   # all, or the board's boosted trees: every one (no prefix is the model)
    else:
        k = min(int(trees), len(models.x.estimators_))
    n_trees = {"x": k, "y": min(k, len(models.y.estimators_)), "energy": n_energy}
    tabs = {"x": forest_tables(models.x, n_trees["x"]), "y": forest_tables(models.y, n_trees["y"]),
            "energy": models.energy_tables(n_trees["energy"])}
    three = models.three_channel_tables()
    head = f"// Generated by `impactsense export` from {Path(model_dir).name} (card {model_hash}); do not edit.\n"
    (out_dir / "impactsense_models.h").write_text(header_h(models, model_hash))
    (out_dir / "impactsense_forest_tables.c").write_text(tables_c(tabs, models, head) + (
        export_check.check_c(models.channel_check) if models.channel_check else ""))
    if write_m2cgen:
        (out_dir / "impactsense_models_m2c.c").write_text(m2cgen_c(models, n_trees, head))
    np.savez(out_dir / "forest_tables.npz", n_features=models.n_features, residual_xy=models.residual_xy,
             signal=json.dumps(models.signal),
             **{f"{r}_inputs": np.asarray(models.inputs[r], dtype=np.uint8) for r in tabs},
             **{f"{r}_{k2}": v for r, t in tabs.items() for k2, v in t.items()},
             **{f"twin_{k2}": v for k2, v in (models.twin or {}).items()},
             **{f"without_{c}_{k2}": v for c, t in three.items() for k2, v in t.items()},
             **export_c.three_position_npz(models.three_position),
             **({"energy_kind": "linear"} if models.energy_linear else {}),
             **export_check.npz_arrays(models.channel_check))
    summary = {
        "model_card_sha256_16": model_hash,
        "features": models.card.get("feature_names"),
        "energy_threshold_j": models.card.get("energy_threshold_j"),
        **({"energy_model": "linear"} if models.energy_linear else {}),
        "n_train_drops": models.card.get("n_train_drops"),
        "data_hash": (models.card.get("split") or {}).get("data_hash"),
        "n_features": models.n_features,
        "inputs": models.inputs,
        "residual_xy": models.residual_xy,
        "signal_fs_hz": models.signal.get("fs_hz"),
        "trees": n_trees,
        "nodes": {r: table_nodes(t) for r, t in tabs.items()},
        "table_bytes": {**{r: table_bytes(t) for r, t in tabs.items()}, "twin": table_bytes(models.twin),
                        **({"three_channel": sum(table_bytes(t) for t in three.values())} if three else {}),
                        **({"three_position": export_c.pairs_bytes(models.three_position)} if models.three_position else {}),
                        **({"channel_check": table_bytes(models.channel_check)} if models.channel_check else {})},
        "table_bytes_total": (sum(table_bytes(t) for t in tabs.values()) + table_bytes(models.twin)
                              + table_bytes(models.channel_check)
                              + sum(table_bytes(t) for t in three.values()) + export_c.pairs_bytes(models.three_position)
                              + sum(len(v) for v in models.inputs.values())),
        "twin": None if models.twin is None else {
            "grid": models.twin["grid"].tolist(), "site_map_bytes": int(models.twin["q"].nbytes)},
        "flash_budget_bytes": MODELS_FLASH_BUDGET,   # of the 256 KB, what the firmware's code leaves
        "tree_sweep": sweep,
        "board_front_end": models.card.get("board_front_end"),   # the analog low-pass the board models assume
    }
    # the board's per-event cost, estimated (board.cost) for every export: the trees chosen, a twin's match
    est = export_check.event_estimate(models, n_trees, signal_cost)
    est["drops"] = export_check.drops_estimate(models, n_trees, est)   # the rig's own drops, each priced whole
    summary["event_instructions_estimate"] = est
    summary.update(export_check.verdicts(est))   # "ok", "near" (measure it on qemu) or "OVER"
    summary["within_budget"] = summary["table_bytes_total"] <= summary["flash_budget_bytes"]
    summary["channel_check"] = bool(models.channel_check) if models.check_note is None else models.check_note
    summary.update(export_check.four_channel_summary(models))
    (out_dir / "export.json").write_text(json_text(summary))
    return summary


def load_tables(path) -> dict:
    """The emulator's copy of the exported tables and settings."""
    z = np.load(Path(path))
    out = {r: {k: z[f"{r}_{k}"] for k in (*TABLE_KEYS, "inputs") if f"{r}_{k}" in z.files}
           for r in ("x", "y", "energy")}
    out.update(n_features=int(z["n_features"]), residual_xy=bool(z["residual_xy"]),
               signal=json.loads(str(z["signal"])))
    if "energy_kind" in z.files:     # the linear estimate's arrays (height_class.linear_tables)
        out["energy"]["kind"] = str(z["energy_kind"])
    twin_keys = [k for k in z.files if k.startswith("twin_")]
    out["twin"] = {k[len("twin_"):]: z[k] for k in twin_keys} if twin_keys else None
    # the three-channel classes (linear_tables per channel; absent: none)
    out["three_channel"] = ({c: {k: z[f"without_{c}_{k}"] for k in TABLE_KEYS if f"without_{c}_{k}" in z.files}
                             for c in range(4)} if "without_0_roots" in z.files else None)
    out["channel_check"] = export_check.from_npz(z)
    out["three_position"] = export_c.three_position_from_npz(z)
    return out


def shipped_board_model() -> Path | None:
    """The board model the repository ships in models/ (what `pio run` builds): installed with the package as
    impactsense/board-model (CMakeLists.txt), read from the source tree's models/ in a development install.
    None if neither is there."""
    here = Path(__file__).resolve().parent
    for d in (here / "board-model", here.parents[1] / "models"):
        if (d / "forest_tables.npz").is_file():
            return d
    return None


def firmware_models(path, three_position=True):
    """(`_link.ForestModels`, card signal dict) of an export folder; three_position: the pairs' channels (True: all)."""
    from . import _core  # noqa: F401  (registers CoreConfig for _link)
    from . import _link

    path = Path(path)
    if path.is_dir():
        path = path / "forest_tables.npz"
    if not path.is_file():
        raise ExportError(f"{path}: no exported forest tables (run `impactsense export`)")
    t = load_tables(path)
    spec = {r: {k: v if isinstance(v, str) else v.tolist() for k, v in t[r].items()} for r in ("x", "y", "energy")}
    twin = None if t["twin"] is None else {k: v.tolist() for k, v in t["twin"].items()}
    three = None if t["three_channel"] is None else [
        {**{k: v.tolist() for k, v in t["three_channel"][c].items()}, "inputs": list(range(_core.THREE_CHANNEL_INPUTS)),
         "kind": "linear"} for c in range(4)]
    return (_link.ForestModels(spec["x"], spec["y"], spec["energy"], t["residual_xy"], twin, three,
                               export_check.binding_dict(t["channel_check"]),
                               export_c.three_position_binding(t["three_position"], three_position)), t["signal"])
