"""Lab faults put into recordings: mains hum, DC offsets, glitches, gain drift, noise, a dead or debonded
channel. `impactsense inject` and `impactsense emulate --inject` use it to replay a faulty lab.

Every fault is drawn from a seeded generator, per record (hum phase and slow amplitude change, offsets,
glitch positions) or per session (which way each channel's gain drifts, the debond's cut-off), so two
runs with the same seed give the same recordings and other seeds give other draws of the same kinds.
The signal model is additive on counts about the rig's bias:
    y = clip(round(bias + g_c(r) * D_c[s - bias] + hum + offset + noise) + glitch)
D_c is the channel's sensor path (x0 for a dead channel, x0.4 and a first-order low-pass for a debonded
one, identity otherwise) and g_c(r) its gain drift over the records of the session.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
from scipy import signal

from .errors import ConfigError


@dataclass
class FaultSpec:
    hum: float = 0.0              # mains hum amplitude (counts, per channel up to this)
    hum_hz: float = 50.0          # mains frequency (50 or 60)
    offset: float = 0.0           # sd of the per-record, per-channel DC offset (counts)
    glitch: float = 0.0           # fraction of records with a 1-2 sample spike of 200..2000 counts
    drift: float = 0.0            # each channel's gain drifts within 1 +- drift over the session
    noise: float = 0.0            # white noise sd (counts)
    dead_channel: int = -1        # this channel carries no signal (its faults stay)
    debond: int = -1              # this channel reads x debond_gain through a first-order low-pass
    debond_gain: float = 0.4
    debond_hz: float = 0.0        # cut-off; 0 = drawn in 3..5 kHz
    seed: int = 0

    def active(self) -> bool:
        return any(getattr(self, f.name) != f.default for f in fields(self) if f.name != "seed")

    def describe(self) -> str:
        return ",".join(f"{f.name}={getattr(self, f.name):g}" for f in fields(self)
                        if getattr(self, f.name) != f.default)


GLITCH_COUNTS = (200.0, 2000.0)
HUM_AMPLITUDE_CHANGE = 0.2        # the hum's amplitude changes by up to this fraction across a record


def parse_spec(text: str, **base) -> FaultSpec:
    """'hum=40,glitch=0.1,offset=8,...' (the FaultSpec field names, dashes allowed) -> FaultSpec."""
    names = {f.name: f.type for f in fields(FaultSpec)}
    kw = dict(base)
    for item in filter(None, (t.strip() for t in (text or "").split(","))):
        key, _, val = item.partition("=")
        key = key.strip().replace("-", "_")
        if key not in names or not val:
            raise ConfigError(f"--inject: {item!r}: expected NAME=VALUE with NAME one of {', '.join(names)}")
        try:
            kw[key] = int(val) if names[key] in ("int", int) else float(val)
        except ValueError:
            raise ConfigError(f"--inject: {item!r}: {val!r} is not a number") from None
    return validate(FaultSpec(**kw))


def validate(spec: FaultSpec) -> FaultSpec:
    for name in ("hum", "offset", "glitch", "drift", "noise", "debond_hz"):
        if getattr(spec, name) < 0:
            raise ConfigError(f"fault {name} must be >= 0, got {getattr(spec, name)}")
    if spec.glitch > 1:
        raise ConfigError(f"fault glitch is a fraction of records (0..1), got {spec.glitch}")
    for name in ("dead_channel", "debond"):
        if not -1 <= getattr(spec, name) < 4:
            raise ConfigError(f"fault {name} must be a channel 0..3 (or -1 for none), got {getattr(spec, name)}")
    if spec.dead_channel >= 0 and spec.dead_channel == spec.debond:
        raise ConfigError("fault dead_channel and debond name the same channel")
    if not 0 < spec.debond_gain <= 1:
        raise ConfigError(f"fault debond_gain must be in (0, 1], got {spec.debond_gain}")
    return spec


def _sensor_path(sig: np.ndarray, spec: FaultSpec, fs_hz: float, rng) -> np.ndarray:
    """Dead and debonded channels (sig: float [R, 4, S] about the bias)."""
    if spec.debond >= 0:
        fc = spec.debond_hz or float(rng.uniform(3000.0, 5000.0))
        b, a = signal.butter(1, min(fc, 0.45 * fs_hz), fs=fs_hz)
        sig[:, spec.debond] = spec.debond_gain * signal.lfilter(b, a, sig[:, spec.debond], axis=-1)
    if spec.dead_channel >= 0:
        sig[:, spec.dead_channel] = 0.0
    return sig


def _drift(n_rec: int, spec: FaultSpec, rng) -> np.ndarray:
    """Gain g_c(r) [R, 4]: a slow sinusoid of random phase and rate, within 1 +- drift."""
    r = np.arange(n_rec)[:, None] / max(n_rec, 1)
    phase = rng.uniform(0, 2 * np.pi, 4)[None]
    cycles = rng.uniform(0.3, 1.0, 4)[None]
    return 1.0 + spec.drift * np.sin(2 * np.pi * cycles * r + phase)


def _hum(shape, spec: FaultSpec, fs_hz: float, rng) -> np.ndarray:
    """Hum [R, 4, S]: per record a random phase, per channel an amplitude in 0.5..1 x hum, slowly changing."""
    n_rec, n_ch, n = shape
    t = np.arange(n) / fs_hz
    amp = spec.hum * rng.uniform(0.5, 1.0, (n_rec, n_ch, 1))
    change = 1.0 + HUM_AMPLITUDE_CHANGE * rng.uniform(-1, 1, (n_rec, n_ch, 1)) * (t / max(t[-1], 1e-9) - 0.5)
    phase = rng.uniform(0, 2 * np.pi, (n_rec, 1, 1)) + rng.uniform(-0.3, 0.3, (n_rec, n_ch, 1))
    return amp * np.clip(change, 0.0, 1.0) * np.sin(2 * np.pi * spec.hum_hz * t + phase)


def _glitches(out: np.ndarray, spec: FaultSpec, rng) -> None:
    """1- or 2-sample spikes of 200..2000 counts, either sign, at any sample of a random channel."""
    n_rec, n_ch, n = out.shape
    hit = np.flatnonzero(rng.random(n_rec) < spec.glitch)
    for r in hit:
        c = int(rng.integers(n_ch))
        i = int(rng.integers(1, n - 2))
        size = rng.uniform(*GLITCH_COUNTS) * rng.choice([-1.0, 1.0])
        width = int(rng.integers(1, 3))
        out[r, c, i:i + width] += size


def inject(adc: np.ndarray, spec: FaultSpec, fs_hz: float, bias: float, adc_max: int) -> np.ndarray:
    """Recordings (uint16 [R, 4, S]) with the faults of `spec`; the input is not changed."""
    spec = validate(spec)
    rng = np.random.default_rng(spec.seed)
    sig = np.asarray(adc, float) - bias
    sig = _sensor_path(sig, spec, fs_hz, rng)
    if spec.drift:
        sig *= _drift(sig.shape[0], spec, rng)[:, :, None]
    if spec.hum:
        sig += _hum(sig.shape, spec, fs_hz, rng)
    if spec.offset:
        sig += rng.normal(0.0, spec.offset, sig.shape[:2] + (1,))
    if spec.noise:
        sig += rng.normal(0.0, spec.noise, sig.shape)
    if spec.glitch:
        _glitches(sig, spec, rng)
    return np.clip(np.rint(sig + bias), 0, adc_max).astype(np.uint16)


def inject_session(session, spec: FaultSpec):
    """A Session with the faults in its recordings (same drops, same folder name until written)."""
    from dataclasses import replace

    rig = session.rig
    adc = inject(session.adc, spec, float(rig.fs_hz), float(rig.bias_counts), int(rig.adc_max))
    return replace(session, adc=adc)
