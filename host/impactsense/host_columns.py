"""Location inputs read from the core's per-channel outputs beside its feature vector (host only).

Each channel's early-arrival spectral tilt, from the core's difference energies over [ToA, ToA + diff_window_us]
(impactcore.h ChannelFeatures.diff_energy: by Parseval the arrival's spectral moments weighted by
(2 sin(pi f / fs))^(2k)), and the period of the cycle its onset caught (pick_period). A gain cancels in every
ratio. Near an edge the reflected copy colours the first cycles of a channel's arrival and moves its pick
(docs/findings.md "Session 21: rigcsite"); the tilt says how, per channel, where the arrival times alone cannot
(docs/findings.md "Session 22: rigcpos"). No signal logic here: ratios of numbers the core computed.

A model without a site map trained with its members (ImpactModel.fit) reads them after the core's location
features (the card's location_features names them); the board's pair never does (the board has no raw outputs).
"""

from __future__ import annotations

import numpy as np

# Per channel c: log10 D2/D1, log10 D3/D2 (the tilt), log10 D1/E (the early arrival's share of the whole
# capture's energy) and the picked cycle's period (samples).
HOST_LOCATION_FEATURES = [f"{kind}_{c}" for c in range(4)
                          for kind in ("early_tilt_21", "early_tilt_32", "early_share", "pick_period")]


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
