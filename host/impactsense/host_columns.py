"""Location inputs read from the core's per-channel outputs beside its feature vector (host only).

Each channel's early-arrival spectral tilt, from the core's difference energies over [ToA, ToA + diff_window_us]
(impactcore.h ChannelFeatures.diff_energy: by Parseval the arrival's spectral moments weighted by
(2 sin(pi f / fs))^(2k)), and the period of the cycle its onset caught (pick_period). A gain cancels in every
ratio. Near an edge the reflected copy colours the first cycles of a channel's arrival and moves its pick
(docs/findings.md "Session 21: rigcsite"); the tilt says how, per channel, where the arrival times alone cannot
(docs/findings.md "Session 22: rigcpos"). No signal logic here: ratios of numbers the core computed.

A model without a site map trained with its members and its edge choice (ImpactModel.fit, `train DATA`) reads
them after the core's location features (the card's location_features names them) when the training drops'
out-of-fold positions say they help (choose_host_columns: the one-standard-error rule of the correction's other
choices; the card's "host_location_inputs"); the board's pair never does: it reads the core's feature vector only.
"""

from __future__ import annotations

import numpy as np

# Per channel c: log10 D2/D1, log10 D3/D2 (the tilt), log10 D1/E (the early arrival's share of the whole
# capture's energy) and the picked cycle's period (samples).
HOST_LOCATION_FEATURES = [f"{kind}_{c}" for c in range(4)
                          for kind in ("early_tilt_21", "early_tilt_32", "early_share", "pick_period")]
# "auto": as the training drops' out-of-fold rule says (choose_host_columns); "always" / "never": that, its choice
# still recorded (benchmarks/bench_rigs.py --host-columns: the held-out figure of the other answer).
HOST_CHOICE = "auto"


def host_columns(raw: dict) -> np.ndarray:
    """[R, len(HOST_LOCATION_FEATURES)] float32 from the core's raw outputs (pipeline.Features.raw). A channel
    without a picked period takes the mean of the drop's other periods (0 when it has none)."""
    d = np.log10(np.asarray(raw["diff_energy"], float) + 1.0)          # [R, 4, 3]
    e = np.log10(np.asarray(raw["energy"], float) + 1.0)               # [R, 4]
    period = np.asarray(raw["pick_period"], float)                     # [R, 4]
    have = np.isfinite(period)
    fill = np.where(have.any(1), np.nansum(np.where(have, period, 0.0), 1) / np.maximum(have.sum(1), 1), 0.0)
    period = np.where(have, period, fill[:, None])
    per_channel = np.stack([d[:, :, 1] - d[:, :, 0], d[:, :, 2] - d[:, :, 1], d[:, :, 0] - e, period], 2)
    return per_channel.reshape(len(e), -1).astype(np.float32)          # channel-major, as the names


def location_matrix(features, names: list[str]) -> np.ndarray:
    """The location inputs `names` of every row of `features` (pipeline.Features), in that order: the core's
    feature vector's columns and HOST_LOCATION_FEATURES."""
    from .pipeline import FEATURE_NAMES

    host = [n for n in names if n in HOST_LOCATION_FEATURES]
    if not host:
        return features.vector[:, [FEATURE_NAMES.index(n) for n in names]]
    extra = host_columns(features.raw)
    cols = [features.vector[:, FEATURE_NAMES.index(n)] if n in FEATURE_NAMES
            else extra[:, HOST_LOCATION_FEATURES.index(n)] for n in names]
    return np.stack(cols, 1).astype(np.float32)


def location_names(left_out, host: bool) -> list[str]:
    """The position forests' inputs: the core's location features that read no left-out channel's onset and,
    with `host`, the HOST_LOCATION_FEATURES of the channels in use."""
    from .models import LOCATION_FEATURES
    from .pipeline import columns_reading

    names = columns_reading(left_out, LOCATION_FEATURES)
    return names + [n for n in HOST_LOCATION_FEATURES if host and not left_out[int(n[-1])]]


def choose_host_columns(train, xy: np.ndarray, signal, positions: dict | None, edge: dict, settings) -> dict | None:
    """Whether the position forests of a model trained on `train` (pipeline.Features of the training drops, true
    positions xy) read HOST_LOCATION_FEATURES: correction_scale.choose_extra_inputs on the training drops, grouped
    by site, with the members the model fits (positions: position_members.member_positions of train or None; edge:
    the chosen edge correction or {}). Returns its record ({"keep", "out_of_fold_mae_mm": [without, with],
    "gain_sigmas", "without", "with"} plus "board") or None with too few sites."""
    from .correction_scale import choose_extra_inputs
    from .position_members import edge_positions

    left_out = signal.channel_left_out
    core, more = location_names(left_out, False), location_names(left_out, True)
    if more == core:
        return None
    base = positions if positions is not None and float(signal.band_velocity_mm_per_us) > 0 else None
    edges = edge_positions(train, signal, edge) if edge else None
    choice = choose_extra_inputs(location_matrix(train, core), location_matrix(train, more),
                                 np.asarray(train.phys_xy_mm, float), base, edges or None, np.asarray(xy, float),
                                 settings, core, more)
    if choice is None:
        return None
    out = {k: v for k, v in choice.items() if k not in ("with", "without")}
    if HOST_CHOICE != "auto":
        out["rule_keep"], out["keep"] = out["keep"], HOST_CHOICE == "always"
    out["board"] = "the board's pair reads the core's feature vector only"
    return out


def chosen_location_names(train, xy: np.ndarray, signal, positions: dict | None, edge: dict, settings,
                          card: dict) -> list[str]:
    """The position forests' inputs of a model with its members and without a site map: location_names (none of a
    left-out channel's arrival times) with the host's columns when choose_host_columns keeps them (its record in
    card["host_location_inputs"])."""
    host = choose_host_columns(train, xy, signal, positions, edge, settings)
    if host is not None:
        card["host_location_inputs"] = host
    return location_names(signal.channel_left_out, bool(host and host["keep"]))
