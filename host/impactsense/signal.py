"""The signal core's configuration on the host: declared once in C++, built in one place.

The fields of the core's `CoreConfig` and `LocaliserConfig` (name, type, default, board role) are declared
once, in firmware/lib/impactcore/src/impactcore.h (`IMPACTCORE_CONFIG_FIELDS`,
`IMPACTCORE_LOCALISER_FIELDS`); the binding hands them over as tables (`_core.CORE_CONFIG_FIELDS`,
`_core.LOCALISER_CONFIG_FIELDS`). From them this module makes:

- `SignalConfig`: one attribute per field, the form stored in every model card (`to_dict` / `from_dict`);
- `core_config(rig, **overrides)` and `localiser_config(rig, **overrides)`: the core's structs, filled from the
  defaults, then what the rig declares (`rig_settings`), then the overrides (a model card's signal settings,
  a calibration's picker choice, diagnosed delays). Every caller on the host builds the core's
  configuration through these two functions.

Adding a field to the core is one line in impactcore.h: it then appears here, in model cards, in the C the
exporter writes for the board and in the board's copy of it (impactapp::exported_config).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, make_dataclass, replace

import numpy as np

from . import _core


@dataclass(frozen=True)
class ConfigField:
    """One field of the core's configuration, as impactcore.h declares it."""

    name: str
    type: str               # "float" or "int"
    count: int              # 1, or CHANNELS for a per-channel field
    default: object         # float | int | list of those
    role: str               # RATE, ACQUISITION, SAMPLES or COPY (impactcore.h explains them)

    @property
    def c_type(self) -> str:
        return "float" if self.type == "float" else "int32_t"

    def value(self, v):
        """`v` as this field's Python type (a list for per-channel fields); ValueError naming the field."""
        cast = float if self.type == "float" else int
        if self.count == 1:
            return cast(v)
        v = list(v)
        if len(v) != self.count:
            raise ValueError(f"{self.name} needs {self.count} values, got {len(v)}")
        return [cast(x) for x in v]


def _decimal(v, type_: str):
    """The default as written in impactcore.h: float32 values back to their shortest decimal (0.35f -> 0.35)."""
    if isinstance(v, (list, tuple)):
        return [_decimal(x, type_) for x in v]
    return float(str(np.float32(v))) if type_ == "float" else int(v)


def _fields(table) -> tuple[ConfigField, ...]:
    return tuple(ConfigField(str(n), str(t), int(c), _decimal(d, str(t)), str(r)) for n, t, c, d, r in table)


CORE_FIELDS: tuple[ConfigField, ...] = _fields(_core.CORE_CONFIG_FIELDS)
LOCALISER_FIELDS: tuple[ConfigField, ...] = _fields(_core.LOCALISER_CONFIG_FIELDS)
FIELDS: dict[str, ConfigField] = {f.name: f for f in CORE_FIELDS + LOCALISER_FIELDS}


# The core's bond inverse (impactcore.h bond_corner_hz ...): a retrained model's, carried to the board's model.
BOND_INVERSE_FIELDS = ("bond_corner_hz", "bond_gain", "bond_limit_hz")


# Names older model cards and rig.json files used: channel_delay_us held the rig's delays (the board added
# its scan delays), now rig_delay_us beside the acquisition's capture_delay_us.
LEGACY_NAMES = {"channel_delay_us": "rig_delay_us"}


def card_values(d: dict) -> dict:
    """The fields of a model card's `signal` dict (older names mapped, other keys ignored)."""
    out = {LEGACY_NAMES.get(k, k): v for k, v in d.items() if LEGACY_NAMES.get(k, k) in FIELDS}
    return out


def rig_settings(rig) -> dict:
    """What a rig's rig.json decides: sample rate, ADC rails (a 16-bit logger's re-centred, `core_offset`), the
    count-valued defaults scaled to its ADC (`counts_per_core_count`), sensor and plate geometry, the rig's
    declared channel delays (optional key `rig_delay_us`, or `channel_delay_us`), where a record longer than
    the core reads begins the core's window (`record_start`)."""
    offset = core_offset(int(rig.adc_max))
    d = {"fs_hz": float(rig.fs_hz), "adc_min": -offset, "adc_max": int(rig.adc_max) - offset,
         "sample_offset": offset,
         "sensor_x_mm": [float(v) for v in rig.sensor_x_mm], "sensor_y_mm": [float(v) for v in rig.sensor_y_mm],
         "plate_x_mm": float(rig.plate_x_mm), "plate_y_mm": float(rig.plate_y_mm)}
    scale = counts_per_core_count(rig)
    if scale != 1.0:   # impactcore.h's count-valued defaults are a 12-bit, 3.3 V logger's: the same volts here
        for name in COUNT_FIELDS:
            d[name] = float(FIELDS[name].default) * scale
        d["onset_threshold_counts"] = max(d["onset_threshold_counts"], ONSET_MIN_STEPS)
    pre = getattr(rig, "pretrigger_samples", None)
    start = record_start(int(rig.samples), pre, float(rig.fs_hz))
    if start:
        d["record_start"] = start
    baseline = baseline_for_pretrigger(None if pre is None else int(pre) - start)
    if baseline is not None:
        d["baseline_samples"] = baseline
    raw = rig.raw if isinstance(getattr(rig, "raw", None), dict) else {}
    delays = raw.get("rig_delay_us", raw.get("channel_delay_us"))
    if delays is not None:
        d["rig_delay_us"] = [float(v) for v in delays]
    return d


INT16_MAX = 32767
# The baseline segment (impactcore.h's baseline_samples) must end before the first arrival: the core seeks the
# onset from its end. A logger that keeps fewer samples before the hit than the default needs gets a segment
# of this fraction of its quiet start (at least MIN_BASELINE_SAMPLES).
BASELINE_SHARE_OF_PRETRIGGER = 0.75
MIN_BASELINE_SAMPLES = 8
# The quiet start is measured on up to this many recordings spread over the session, by the core's own
# threshold crossing from a short baseline segment at a strict noise factor (mains hum and glitches cannot
# pass for an arrival there), as a low quantile of each recording's earliest channel.
QUIET_START_RECORDINGS = 32
QUIET_START_NOISE_FACTOR = 10.0
QUIET_START_QUANTILE = 25.0


def baseline_for_pretrigger(pretrigger_samples) -> int | None:
    """The core's baseline_samples for recordings whose first arrival comes `pretrigger_samples` after their
    start: None (the default stands) when the default segment ends well before it, else a shorter one."""
    if pretrigger_samples is None:
        return None
    default = int(FIELDS["baseline_samples"].default)
    fitting = int(BASELINE_SHARE_OF_PRETRIGGER * float(pretrigger_samples))
    return None if fitting >= default else max(MIN_BASELINE_SAMPLES, fitting)


def quiet_start_samples(adc, rig) -> int | None:
    """Samples before the first arrival in a session's recordings [R, 4, S] (the logger's pre-trigger, as the
    core sees it), or None when no recording has an onset."""
    adc = np.asarray(adc)
    if adc.ndim != 3 or adc.shape[0] == 0 or adc.shape[2] < 2 * MIN_BASELINE_SAMPLES + 16:
        return None
    rows = np.unique(np.linspace(0, adc.shape[0] - 1, min(adc.shape[0], QUIET_START_RECORDINGS)).astype(int))
    values = settings(rig, baseline_samples=2 * MIN_BASELINE_SAMPLES, onset_noise_factor=QUIET_START_NOISE_FACTOR)
    cfg = _fill(_core.CoreConfig(), CORE_FIELDS, values)
    crossing = _core.extract_batch(core_samples(adc[rows], cfg), cfg)["toa_threshold"]
    crossing = np.where(crossing >= 0, crossing, np.nan)
    earliest = np.nanmin(np.where(np.isfinite(crossing), crossing, np.inf), axis=1)
    earliest = earliest[np.isfinite(earliest)]
    return int(np.percentile(earliest, QUIET_START_QUANTILE)) if earliest.size else None
# The core's defaults in ADC counts (impactcore.h) are those of the reference logger (12 bits over 3.3 V, the
# board's SAADC and the bundled rig's); a rig with another ADC gets them scaled to the same volts.
REFERENCE_ADC_BITS, REFERENCE_VREF = 12, 3.3
COUNT_FIELDS = ("onset_threshold_counts", "dead_rms_counts", "hum_min_counts")
# ... but an onset threshold of at least this many of the logger's own steps: on a coarse logger the scaled
# default falls under one step (an 8-bit, 5 V one: 0.41), the noise factor's 5 x noise rms (~0.4 step) then sets
# it at ~2 steps, and a lone sample 2 steps from the level (quantised noise past 1.5 steps, ~2e-4 of the samples)
# crosses it: a pick in the quiet start. From 2.5 steps such a sample crosses only from a level half a step off.
ONSET_MIN_STEPS = 2.5


def counts_per_core_count(rig) -> float:
    """How many of the rig's ADC counts make one count of the reference logger (the same volts): 1 for a 12-bit,
    3.3 V logger, 16 for a 16-bit one over the same range."""
    return float(2.0 ** (int(rig.adc_bits) - REFERENCE_ADC_BITS) * (REFERENCE_VREF / float(rig.vref)))


def core_offset(adc_max: int) -> int:
    """Counts the host takes off a recording's samples before the core's int16: 0 for an ADC of up to 15
    bits, half its range above (a 16-bit logger re-centred on zero at full resolution)."""
    return 0 if int(adc_max) <= INT16_MAX else (int(adc_max) + 1) // 2


# The core takes captures of at most this many samples per channel (impactcore.h's kMaxSamples); a logger
# that keeps longer records (e.g. 20000 samples at 1 MHz) is read over CORE_MAX_SAMPLES of them: the event's
# windows (ToA .. n2, the difference energies' diff_window_us) end long before.
CORE_MAX_SAMPLES = int(_core.MAX_SAMPLES)
# Where that window starts (impactcore.h's record_start): QUIET_KEPT_S before the session's quiet start (at least
# QUIET_KEPT_MIN_SAMPLES), not at the record's start. Over the quiet start a hum the core does not model drifts
# from the baseline segment's level (the capture's first baseline_samples) by up to 2 A sin(pi f t): at 4 ms and
# 50 Hz 1.2 x its amplitude A, over an onset threshold; over 1 ms 0.31 A. A record of at most CORE_MAX_SAMPLES
# (and one whose quiet start is not known) is read from its start, as before.
QUIET_KEPT_S = 1e-3
QUIET_KEPT_MIN_SAMPLES = 256


def record_start(samples: int, pretrigger_samples: int | None, fs_hz: float) -> int:
    """The first record sample the core reads (impactcore.h's record_start): 0 unless the record is longer than
    CORE_MAX_SAMPLES and keeps more quiet start than QUIET_KEPT_S (QUIET_KEPT_MIN_SAMPLES) before its first
    arrival; then that much before the first arrival, the window never past the record's end."""
    if pretrigger_samples is None or int(samples) <= CORE_MAX_SAMPLES:
        return 0
    keep = max(QUIET_KEPT_MIN_SAMPLES, int(round(QUIET_KEPT_S * float(fs_hz))))
    return int(np.clip(int(pretrigger_samples) - keep, 0, int(samples) - CORE_MAX_SAMPLES))


def core_window(x: np.ndarray, start: int = 0) -> np.ndarray:
    """A record array [..., S] cut to the samples the core reads: CORE_MAX_SAMPLES from `start` (a view; a
    record of at most CORE_MAX_SAMPLES whole, whatever `start`; the window never past the record's end)."""
    n = x.shape[-1]
    if n <= CORE_MAX_SAMPLES:
        return x
    a = min(max(int(start), 0), n - CORE_MAX_SAMPLES)
    return x[..., a:a + CORE_MAX_SAMPLES]


def core_samples(counts, cfg) -> np.ndarray:
    """Recordings in the rig's ADC counts ([R, 4, S] or [4, S], integers or floats) as the core's int16 samples
    for `cfg` (a SignalConfig or the core's CoreConfig): rounded, less cfg.sample_offset, clipped to the rails;
    at most CORE_MAX_SAMPLES of each record from cfg.record_start (`core_window`); C-contiguous. The one
    conversion every path into the core uses."""
    x = np.asarray(counts)
    if x.ndim == 2:
        x = x[None]
    x = core_window(x, int(getattr(cfg, "record_start", 0)))
    off = int(getattr(cfg, "sample_offset", 0))
    lo, hi = max(int(cfg.adc_min), -INT16_MAX - 1), min(int(cfg.adc_max), INT16_MAX)
    if x.dtype.kind == "f":
        x = np.rint(x)
    x = np.clip(x.astype(np.int32) - off, lo, hi)
    return np.ascontiguousarray(x.astype(np.int16))


def settings(rig=None, **overrides) -> dict:
    """Every field's value: impactcore.h's default, then the rig's (`rig_settings`), then `overrides`."""
    unknown = sorted(set(overrides) - set(FIELDS))
    if unknown:
        raise TypeError(f"not fields of the core's configuration: {', '.join(unknown)}")
    values = {name: f.default for name, f in FIELDS.items()}
    if rig is not None:
        values.update(rig_settings(rig))
    values.update(overrides)
    return {name: FIELDS[name].value(v) for name, v in values.items()}


def _fill(obj, fields, values: dict):
    for f in fields:
        setattr(obj, f.name, values[f.name])
    return obj


def core_config(rig=None, **overrides) -> "_core.CoreConfig":
    """The core's CoreConfig for `rig` (None: impactcore.h's defaults) with `overrides` (field=value)."""
    return _fill(_core.CoreConfig(), CORE_FIELDS, settings(rig, **overrides))


def localiser_config(rig=None, **overrides) -> "_core.LocaliserConfig":
    """The core's LocaliserConfig for `rig` with `overrides` (field=value)."""
    return _fill(_core.LocaliserConfig(), LOCALISER_FIELDS, settings(rig, **overrides))


def channel_delays_us(cfg) -> list[float]:
    """The delay the core removes from each channel's ToA (impactcore::channel_delay_us): the rig's plus the
    acquisition's."""
    return [float(r) + float(c) for r, c in zip(cfg.rig_delay_us, cfg.capture_delay_us)]


def with_channel_delays(signal, delays):
    """`signal` (a SignalConfig) whose picks also take `delays` (us per channel) out: added to the rig delays of
    the threshold picks and to the band picks' own delays (the core removes both from every pick)."""
    if not any(delays):
        return signal
    return replace(signal, rig_delay_us=[float(a) + float(d) for a, d in zip(signal.rig_delay_us, delays)],
                   band_delay_us=[float(a) + float(d) for a, d in zip(signal.band_delay_us, delays)])


def config_dict(cfg) -> dict:
    """A CoreConfig or LocaliserConfig as {field: value} (picklable; `core_config(**d)` rebuilds it)."""
    fields = CORE_FIELDS if isinstance(cfg, _core.CoreConfig) else LOCALISER_FIELDS
    return {f.name: f.value(getattr(cfg, f.name)) for f in fields}


class _SignalConfigMethods:
    """The behaviour of SignalConfig; its attributes are the fields of impactcore.h."""

    @classmethod
    def for_rig(cls, rig, **overrides):
        return cls(**settings(rig, **overrides))

    @classmethod
    def from_dict(cls, d: dict):
        """From a model card's `signal` dict; keys that are not fields (older cards' extras) are ignored."""
        return cls(**settings(**card_values(d)))

    def to_dict(self) -> dict:
        return asdict(self)

    def core(self) -> "_core.CoreConfig":
        return core_config(**self.to_dict())

    def localiser(self) -> "_core.LocaliserConfig":
        return localiser_config(**self.to_dict())

    @property
    def sensor_xy_mm(self) -> np.ndarray:
        return np.stack([self.sensor_x_mm, self.sensor_y_mm], axis=1)


def _dataclass_field(f: ConfigField):
    kind = float if f.type == "float" else int
    if f.count == 1:
        return f.name, kind, field(default=f.default)
    default = list(f.default)
    return f.name, list[kind], field(default_factory=lambda: list(default))


SignalConfig = make_dataclass(
    "SignalConfig", [_dataclass_field(f) for f in FIELDS.values()], bases=(_SignalConfigMethods,),
    namespace={"__doc__": "Everything the core needs besides the samples (the fields of impactcore.h's "
                          "CoreConfig and LocaliserConfig); stored in every model card."})
SignalConfig.__module__ = __name__

__all__ = ["ConfigField", "CORE_FIELDS", "LOCALISER_FIELDS", "FIELDS", "LEGACY_NAMES", "SignalConfig", "card_values",
           "channel_delays_us", "config_dict", "core_offset", "core_samples", "counts_per_core_count",
           "core_config", "localiser_config", "rig_settings", "settings", "baseline_for_pretrigger",
           "quiet_start_samples", "record_start"]
