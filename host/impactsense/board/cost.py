"""The board's per-event cost (issues 15/17: <= 64,000 instructions an event on the Cortex-M4F), estimated on
the host from what an export chooses, so that the board's refit and `impactsense export` choose within it.

The event is the features (with or without the band picks), the physics localiser (one run, a second with
the band picks' own travel model, each with `localiser_starts` starts), Eq. 35, the feature vector and the
report, and the models (the forests' node tables; the twin's match where the model has one). The estimate is
meant as a bound on every drop, the sum of each part's worst case, each part a measured rate (instructions
under qemu -icount, the image bench_firmware_cost.py builds: `python3 benchmarks/bench_firmware_cost.py
--data DATA --export OUT --all`; figures in docs/findings.md, "The event budget's worst case, per rig"):

- BASE_INSTRUCTIONS: the features without the band picks, Eq. 35, the vector and the report, fitted with the
  localiser's bound below: BASE + that bound covers the slowest drop's event less its models, measured over
  every drop of the rigs' board captures (one with a channel whose mains hum is modelled; a capture with more
  such channels is not covered); the features' and the localiser's slowest drops differ, so BASE alone is
  below the slowest features and report. FRONT_END_INSTRUCTIONS more when the board's captures pass a declared
  analog front end (rig.json `board_front_end`, the model card's record; base_instructions): the low-passed
  arrivals' first lobes are smaller against the later ones, so the features' peak scan (and the baseline fit)
  read more blocks (a median ~1.7k a drop on the captures through the README's front end). Fitted the same
  way: since the peak scan tests a passing group's blocks in its own loop, BASE + the localiser's bound
  covers the slowest front-end drops by 1.2-2.1k without this share, which is kept as a margin
  (docs/findings.md "Session 24: aacheap");
- band picks: per channel, each sample the demodulator filters (the window from kBandBeforeUs before the
  first onset to band_window_us after it, plus the cascade's settling), BAND_PER_SAMPLE instructions;
- a twin model's match (twin_instructions), and export_check.event_estimate's sum of the parts (event_parts);
  board/drop_cost.py prices each of the model's own drops whole instead (what export's verdict reads);
- localiser: a bound, not a typical run: the screening (LOCALISER_SCREEN) and, for each start, at most
  LOCALISER_EVALUATIONS normal-equation evaluations (impactcore's localise.cpp stops there; fewer where the
  signal's localiser_evaluation_cap caps them) at LOCALISER_PER_EVALUATION each; an anisotropic plate (a travel
  metric) runs the costlier form;
- forests: FOREST_PER_NODE for each node a tree visits (its leaf included) and FOREST_PER_TREE for each tree,
  the nodes counted on each tree's deepest path (deepest_walks: no drop walks more), FOREST_PER_INPUT for each input a forest reads
  (impactapp's forest_mean takes each input's order key once a call), plus FOREST_FIXED (the inputs' gathering,
  the calls, the vote). forest_mean walks a split node in 9 (left) or 10 (right) instructions and a tree's
  root, count and leaf in ~12, so a tree of s splits costs at most 10 s + 12 = 10 (nodes - 1) + 12: counting
  the leaf as a node at 11 bounds it with one spare a node (a boosted depth-3 tree: 44 against 42).
"""

from __future__ import annotations

import math

import numpy as np

EVENT_BUDGET = 64000
BASE_INSTRUCTIONS = 53000
FRONT_END_INSTRUCTIONS = 500
BAND_PER_SAMPLE = 80
# impactcore bond_inverse.cpp (a channel with bond_corner_hz > 0): its loop on the M4F (the board build's
# arm-none-eabi -O2 -ffp-contract=off, counted from the listing: 16 a sample on a 12-bit ADC's rails, one USAT,
# about 18 on other rails, and a pass's 3 over eight samples; qemu's -Os build 13.6) over the channel's span only
# (bond_span_end, docs/method.md "Bond inverse"): from the capture start to the other channels' first crossing (on
# the board's captures at most BOND_ANCHOR_FRAMES: the trigger's pretrigger of 96 frames at 50 kHz and a plate
# crossing) + kBondReach x the difference window + aic_after. The channel's other passes then read the span only,
# which is not counted here (a margin).
BOND_PER_SAMPLE = 17
BOND_ANCHOR_FRAMES = 128
BOND_REACH = 2          # impactcore.h kBondReach
BOND_SPAN_MAX = 2048    # impactcore.h kBondSpanMax
# impactcore localise.cpp's kMaxEvaluations (a start's normal-equation evaluations, step halvings included)
LOCALISER_EVALUATIONS = 16
# (isotropic, anisotropic plate): the screening's 20 points, the set-up and the covariance; one evaluation
# (qemu, every drop of four rigs' exports: at most 273 / 333 an evaluation above the screening; the anisotropic
# form 368 before normal_eqs held the metric in registers, docs/findings.md "Session 24: aacheap"). The screening
# refitted by `python3 benchmarks/bench_export_estimate.py --fit` (Session 26: at 280 an evaluation the bundled
# plate's drops need 2,380 isotropic, four plates' 2,934 metric)
LOCALISER_SCREEN = (2400, 2950)
LOCALISER_PER_EVALUATION = (280, 335)
# The posterior mean (impactcore.h posterior_grid): per grid point, per localiser run, one Huber cost (four
# travel distances, the t0 passes) and an expf; an estimate, not measured under qemu (no board model uses it:
# 15 x 15 points cost more than the event budget).
POSTERIOR_PER_POINT = 450
# The forests' walk, refitted on the qemu image's models stage (TICKS_DROP models, every drop of two rigs' exports,
# boosted and random forests; docs/findings.md "Session 22: boardcost"): the models less 10 a split and 12 a tree is
# 1,620-1,711 with 40 order keys and 14 linear terms, i.e. ~1,010 beyond them; FOREST_FIXED keeps ~40 over that.
FOREST_PER_NODE = 11
FOREST_PER_TREE = 0
FOREST_FIXED = 1050
# ... and when the energy class is a forest (not the linear estimate): its vote beyond the walk and the keys. Measured
# under qemu on three exports with a 2-tree class forest (15 inputs, 10 nodes) and 8 boosted stages a coordinate
# (docs/findings.md "Session 23: boardfit"): the models 2,202-2,210, 8-22 above FOREST_FIXED + the walk + the keys
# (the walk counted at its deepest path: no drop walks more; 22 on a one-tree export); ~40 kept over that.
CLASS_FOREST_FIXED = 60
# forest_mean's order key of one input (load, two ALU operations, store and the loop: 7 instructions, qemu image)
FOREST_PER_INPUT = 7
# A term of the linear energy estimate (impactapp::linear_terms): three factor slots, each a load and a compare and,
# where used, two loads, a subtract and two multiplies; an upper estimate (qemu's models stage on a laminate's
# export, 1 + 1 localisation trees and 14 terms, is 1,660 instructions; docs/findings.md "The energy class chosen
# per training set")
LINEAR_PER_TERM = 30
# What the board's refit leaves the models when it chooses the signal's options: at least the cheapest forests
# (one tree each: one boosted stage a coordinate with 20 inputs each and 14 linear energy terms measures 1,787 under
# qemu); export.select_trees then fits the forests into what is left.
MODELS_ALLOWANCE = 1850

# The channel check (impactcore channelcheck.cpp, impactapp App::check_event) on every event of a model that carries
# it: the ratios, each channel's cubic at the physics position, the run rule (measured under qemu on a board
# export, docs/findings.md "The channel check on the board"; a margin on top)
CHECK_INSTRUCTIONS = 1000
# ... and on an event it flags, instead of the forests: the physics localiser without the channel (impactcore
# three_sensor_position: the screening and at most FLAGGED_EVALUATIONS evaluations a start, impactcore.h
# kFlaggedEvaluations; three channels: the four-channel rates x 0.8, as normal_eqs<3> against normal_eqs<4> under
# qemu, 165 against 211 a call, rounded up), the three-channel inputs (115) and the class's terms (LINEAR_PER_TERM
# each)
FLAGGED_EVALUATIONS = 6
FLAGGED_SCREEN = (1850, 2400)
FLAGGED_PER_EVALUATION = (230, 300)
CHECK_FLAGGED_FIXED = 300

# A twin model's match (impactapp: twin_features and the twin's coarse-to-fine match at the forests' position):
# TWIN_FIXED and TWIN_PER_POINT for each grid point the matches visit, at most twin_points_bound (the lattice
# points within each match's cutoff). Refitted by `python3 benchmarks/bench_export_estimate.py` on the qemu image's
# per-drop twin ticks (docs/findings.md "Session 26: exportest"). A drop whose match the twin doubts runs the cued
# search over kTwinCuedCandidates channels instead (TWIN_CUED_PER_CANDIDATE each): not a clean event's cost, given
# beside the estimate as the flagged event's.
TWIN_FIXED = 2550
TWIN_PER_POINT = 219
TWIN_CUED_CANDIDATES = 4
TWIN_CUED_PER_CANDIDATE = 9400
# A twin model's report is cheaper than a forest model's (no three-channel classes): the event less its features,
# localiser and models measured 2,310-2,548 a drop on two twin exports, 3,434-5,481 on four forest exports whose
# board ran the channel check (CHECK_INSTRUCTIONS of it): BASE_INSTRUCTIONS less the difference of the maxima.
TWIN_REPORT_CREDIT = 1600

# The per-drop form (board.drop_cost: each of the rig's own drops priced whole on the host's counts of the same
# C++ on the same board captures). The features and report per drop: FEATURES_FIXED (a forest or a twin model's:
# their reports differ) + FEATURES_PER_COUNT x the core's work counters (impactcore.h WorkCounts; a counter no run
# varied gets no rate): a linear programme's bound at or above every clean drop of the qemu runs (the event less its
# localiser, its models, the bond inverse's bound and the check's share), the least total slack; export's verdict
# (export_check.estimate_total) reads it, and on a session with a modelled hum not below the parts' worst cases.
# Refitted by `python3 benchmarks/bench_export_estimate.py --fit Q...json` (docs/findings.md "Session 26:
# exportest": the runs, each run left out of the fit, estimate / measured per run). hum_channels: that fit's 6,136.6
# less what a hum channel's path lost since (qemu, session-2 with hum on four channels: 1,290 in Session 27
# boardhum, 713 in Session 28 boardhum2, 917 in Session 29 boardhum3, 630 in Session 30 boardhum4).
FEATURES_FIXED = {"forests": 41027.0, "twin": 40601.0}
FEATURES_PER_COUNT = {"peak_blocks": 199.2, "hum_fits": 482.4, "hum_channels": 2587.9, "spike_hunts": 301.3,
                      "transients": 1785.5, "reach_tests": 12.4, "crossing_blocks": 12.2}

# How far export's estimate is from qemu's slowest clean event, estimate / qemu, by which estimate the verdict reads
# (export_check.estimate_form): "drops" (the model's session has no modelled hum: its drops priced whole), "hum" (a
# session with a hum or a channel redone: the larger of the drops and the parts), "parts" (no session at hand: the
# parts' worst cases). Measured with each run's per-drop rates fitted without that run (`python3
# benchmarks/bench_export_estimate.py Q...json --loo FIT_RUNS...`), rounded outwards to 0.01 (docs/findings.md
# "Session 26: exportfix"). FLAGGED_RATIO_HIGH: the flagged event's estimate / qemu's slowest flagged event, at most.
# export_check.event_verdict: "ok" when estimate / low <= EVENT_BUDGET (even its worst under-count fits), "OVER" when
# estimate / high > EVENT_BUDGET (even its worst over-count does not), otherwise "near" (measure it on qemu).
# The "hum" band's low end is the stored alu-large-thin run's (four hum channels on every drop), whose qemu figure
# predates four cheaper hum paths (Sessions 27 boardhum, 28 boardhum2, 29 boardhum3 and 30 boardhum4, ~3.5k a hum channel
# together; its session was not remade): with hum_channels' rate lowered by that it reads 0.517 (0.62 with the old rate).
ESTIMATE_RATIO_BAND = {"drops": (1.04, 1.22), "hum": (0.51, 1.13), "parts": (0.39, 1.27)}
FLAGGED_RATIO_HIGH = 1.35

# impactcore.h's band pick geometry (bandpick.cpp): the window before the first onset, the cascade's poles and
# its cut-off divisor, the longest window kept.
_BAND_BEFORE_US = 300.0
_BAND_POLES = 4
_BAND_CUTOFF_DIVISOR = 6.0
_BAND_MAX_WINDOW = 512


def band_samples(cfg) -> int:
    """Samples one channel's band pick filters (settling + window), 0 when the band picks are off."""
    fs, f0 = float(cfg.fs_hz), float(cfg.band_pick_hz)
    if not (f0 > 0 and fs > 0 and float(cfg.band_velocity_mm_per_us) > 0):
        return 0
    wc = 2 * math.pi * (f0 / _BAND_CUTOFF_DIVISOR) / fs
    alpha = wc / (1 + wc)
    window = int(_BAND_BEFORE_US * 1e-6 * fs + 0.5) + int(float(cfg.band_window_us) * 1e-6 * fs + 0.5)
    return min(window, _BAND_MAX_WINDOW) + int(2 * _BAND_POLES / alpha + 0.5)


def bond_samples(cfg) -> int:
    """Samples a bonded channel's inverse filters on the board (bond_span_end at the slowest anchor): 0 when no
    channel has the inverse on."""
    if not any(float(fc) > 0.0 for fc in getattr(cfg, "bond_corner_hz", ())):
        return 0
    fs = float(cfg.fs_hz)
    window = int(float(cfg.diff_window_us) * 1e-6 * fs + 0.5)
    if window <= 0:
        return BOND_SPAN_MAX
    reach = BOND_REACH * window + int(cfg.aic_after)
    if float(cfg.band_pick_hz) > 0.0:
        reach = max(reach, int(float(cfg.band_window_us) * 1e-6 * fs + 0.5))
    return min(BOND_SPAN_MAX, BOND_ANCHOR_FRAMES + 1 + reach)


def isotropic(metric) -> bool:
    """A travel metric (Q_xx, Q_xy, Q_yy) the core reads as the Euclidean distance (localise_tdoa's iso form)."""
    return tuple(float(q) for q in metric) == (1.0, 0.0, 1.0)


def evaluations_cap(cfg) -> int:
    """A start's normal-equation evaluations at most (impactcore.h localiser_evaluation_cap; 0: the core's cap)."""
    n = int(getattr(cfg, "localiser_evaluation_cap", 0) or 0)
    return n if 0 < n < LOCALISER_EVALUATIONS else LOCALISER_EVALUATIONS


def localiser_run_instructions(starts: int = 1, iso: bool = True, evaluations: int = LOCALISER_EVALUATIONS) -> int:
    """A bound on one localiser run: the screening and every start at its evaluation cap (`evaluations`)."""
    k = 0 if iso else 1
    return LOCALISER_SCREEN[k] + max(1, int(starts)) * int(evaluations) * LOCALISER_PER_EVALUATION[k]


def base_instructions(front_end=None) -> int:
    """BASE_INSTRUCTIONS, plus FRONT_END_INSTRUCTIONS when the board's captures pass an analog front end:
    front_end is the model card's `board_front_end` ({"anti_alias_hz", "anti_alias_poles"}), the capture's
    (corner Hz, poles) (board.capture.board_anti_alias), or None / {} without one."""
    if isinstance(front_end, dict):
        front_end = front_end.get("anti_alias_hz")
    elif front_end is not None:
        front_end = tuple(front_end)[0]
    return BASE_INSTRUCTIONS + (FRONT_END_INSTRUCTIONS if front_end is not None and float(front_end) > 0 else 0)


def signal_instructions(cfg, channels: int = 4, front_end=None) -> dict:
    """The event's cost without the models (instructions): {'base', 'band', 'localiser', 'total'} for the
    signal configuration cfg (pipeline.SignalConfig) at its rate, on captures through front_end
    (base_instructions; 'base' with the bond inverse's on its channels)."""
    band = channels * BAND_PER_SAMPLE * band_samples(cfg)
    starts, cap = max(1, int(cfg.localiser_starts)), evaluations_cap(cfg)
    loc = localiser_run_instructions(starts, isotropic((cfg.travel_metric_xx, cfg.travel_metric_xy,
                                                        cfg.travel_metric_yy)), cap)
    grid = int(getattr(cfg, "posterior_grid", 0))
    posterior = POSTERIOR_PER_POINT * grid * grid if grid > 1 else 0
    loc += posterior
    if band:
        loc += localiser_run_instructions(starts, isotropic((cfg.band_metric_xx, cfg.band_metric_xy,
                                                             cfg.band_metric_yy)), cap) + posterior
    base = base_instructions(front_end)
    bond = BOND_PER_SAMPLE * bond_samples(cfg)   # kMaxBondChannels: one channel at most
    return {"base": base + bond, "band": band, "localiser": loc, "total": base + bond + band + loc}


def signal_fits(cfg, front_end=None) -> bool:
    """Whether cfg's options leave the models their allowance of the event budget (captures through
    front_end: base_instructions)."""
    return signal_instructions(cfg, front_end=front_end)["total"] + MODELS_ALLOWANCE <= EVENT_BUDGET


def forest_nodes(forest, X: np.ndarray) -> np.ndarray:
    """Nodes each tree of a scikit-learn forest visits for each row of X (leaf included): int [trees, rows]."""
    X = np.asarray(X, dtype=np.float32)
    return np.stack([np.asarray(t.decision_path(X).sum(axis=1)).ravel() for t in forest.estimators_])


def deepest_walks(forest) -> np.ndarray:
    """Nodes on each tree's deepest path (its leaf included), int [trees, 1]: what forest_nodes gives on the slowest
    row any drop can be, so a bound that does not depend on which drops were at hand (a few held-out drops of a
    small session walk less of a deep random tree than others do: docs/findings.md "Session 23: boardfit")."""
    return np.array([[int(t.tree_.max_depth) + 1] for t in forest.estimators_], dtype=np.int64).reshape(-1, 1)


def linear_instructions(n_terms: int) -> int:
    """The linear energy estimate's cost (impactapp::linear_terms): LINEAR_PER_TERM a term (its coefficient and up
    to three standardised factors); the inputs' gathering and the call are in FOREST_FIXED."""
    return LINEAR_PER_TERM * int(n_terms)


def forests_instructions(nodes: dict, trees: dict, inputs: dict | None = None) -> int:
    """The models' cost for the prefixes `trees` (role -> number of trees) of forests whose node counts are
    `nodes` (role -> forest_nodes) and which read `inputs` (role -> number of inputs; absent: none counted): the
    slowest row. An "energy" role is the class forest (CLASS_FOREST_FIXED more)."""
    per_row = sum(FOREST_PER_NODE * nodes[r][:k].sum(axis=0) + FOREST_PER_TREE * k for r, k in trees.items())
    per_input = FOREST_PER_INPUT * sum(int((inputs or {}).get(r, 0)) for r, k in trees.items() if k > 0)
    vote = CLASS_FOREST_FIXED if trees.get("energy", 0) > 0 else 0
    return FOREST_FIXED + vote + per_input + (int(np.max(per_row)) if np.size(per_row) else 0)


def flagged_run_instructions(starts: int = 1, iso: bool = True) -> int:
    """A bound on one localiser run of a flagged event's three-sensor position: the screening and every start at
    FLAGGED_EVALUATIONS."""
    k = 0 if iso else 1
    return FLAGGED_SCREEN[k] + max(1, int(starts)) * FLAGGED_EVALUATIONS * FLAGGED_PER_EVALUATION[k]


def check_instructions(cfg, three_terms: int) -> dict:
    """The channel check's share of an event (instructions): 'check' on every event and 'flagged', what an event it
    flags runs instead of the forests (a localiser run without the channel, with the band picks' when they are on,
    and the three-channel class of three_terms terms)."""
    starts = max(1, int(cfg.localiser_starts))
    loc = flagged_run_instructions(starts, isotropic((cfg.travel_metric_xx, cfg.travel_metric_xy,
                                                      cfg.travel_metric_yy)))
    if band_samples(cfg):
        loc += flagged_run_instructions(starts, isotropic((cfg.band_metric_xx, cfg.band_metric_xy,
                                                           cfg.band_metric_yy)))
    return {"check": CHECK_INSTRUCTIONS, "flagged": loc + CHECK_FLAGGED_FIXED + linear_instructions(three_terms)}


def lattice_points_within(radius: float, step: float, samples: int = 16) -> int:
    """The most grid points (spacing step) a disc of `radius` holds, over its centre's place in a grid cell."""
    if not (radius > 0 and step > 0):
        return 0
    k = np.arange(-int(radius / step) - 1, int(radius / step) + 2) * step
    off = (np.arange(samples) + 0.5) / samples * step
    best = 0
    for ox in off:
        dx2 = (k[:, None] - ox) ** 2
        for oy in off:
            best = max(best, int(np.count_nonzero(dx2 + (k[None, :] - oy) ** 2 <= radius * radius)))
    return best


def twin_points_bound(grid, config) -> int:
    """Grid points a clean event's twin match visits at most: the fine match's within cutoff_mm and, with a coarse
    start (coarse_cutoff_mm > 0), every other point within coarse_cutoff_mm (the model's twin arrays: grid
    [nx, ny, x0, y0, step], config [ref, prior, cutoff, temperature, coarse_cutoff, weak])."""
    step, cutoff, coarse = float(grid[4]), float(config[2]), float(config[4])
    return lattice_points_within(cutoff, step) + (lattice_points_within(coarse, 2 * step) if coarse > 0 else 0)


def twin_instructions(twin) -> dict:
    """A twin model's match on a clean event ('twin') and on a drop whose match the twin doubts ('cued': the cued
    search's candidates on top): instructions; {} without a twin."""
    if not twin:
        return {}
    clean = TWIN_FIXED + TWIN_PER_POINT * twin_points_bound(twin["grid"], twin["config"])
    return {"twin": clean, "cued": clean + TWIN_CUED_CANDIDATES * TWIN_CUED_PER_CANDIDATE}


def event_parts(cfg, front_end=None, walks: dict | None = None, trees: dict | None = None,
                inputs: dict | None = None, linear_terms: int = 0, twin: dict | None = None,
                check_terms: int | None = None, check: int | None = None) -> dict:
    """The board's instructions an event, by part: 'base' (the features and report, the bond inverse's with them),
    'band', 'localiser' (signal_instructions), 'check' (the channel check on every event: check_terms is the
    three-channel class's terms when the board runs it, else None; `check` overrides its share, e.g. 0 when export
    kept the check on the host), 'models' (forests_instructions of the prefixes `trees` of forests whose trees'
    deepest walks are `walks` (role -> nodes per tree) reading `inputs`, plus linear_terms of the linear energy
    estimate), 'twin' (twin_instructions) and 'total', their sum. 'flagged': with a twin, the event whose match it
    doubts (the cued search); with the check, an event it flags (check_instructions' 'flagged' instead of the
    forests)."""
    sig = signal_instructions(cfg, 4, front_end)
    parts = {"base": sig["base"] - (TWIN_REPORT_CREDIT if twin else 0), "band": sig["band"],
             "localiser": sig["localiser"]}
    flagged = check_instructions(cfg, check_terms) if check_terms is not None else None
    parts["check"] = int(check) if check is not None else (flagged["check"] if flagged else 0)
    walks, trees = walks or {}, trees or {}
    nodes = {r: np.asarray(w, dtype=np.int64).reshape(-1, 1) for r, w in walks.items()}
    forests = forests_instructions(nodes, {r: int(k) for r, k in trees.items() if r in nodes}, inputs) if nodes else 0
    parts["models"] = forests + linear_instructions(linear_terms)
    t = twin_instructions(twin)
    parts["twin"] = t.get("twin", 0)
    parts["total"] = sum(parts[k] for k in ("base", "band", "localiser", "check", "models", "twin"))
    if t:
        parts["flagged"] = parts["total"] - parts["twin"] + t["cued"]
    elif flagged and parts["check"]:
        parts["flagged"] = parts["total"] - parts["models"] + flagged["flagged"]
    return parts
