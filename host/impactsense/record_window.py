"""Does a session's record hold the far arrivals? The record after the first arrival against the plate's longest
path difference at its flexural group velocity (`impactsense info`, and `train` warns).

A drop's first arrival reaches the nearest sensor; the last one the farthest, (max_k d_k - min_k d_k) / v later
(d_k the distances from the drop to the sensors). Over the plate the largest of those differences is the span
the record must keep after its first arrival. v: the materials table's typical values through the Mindlin
flexural group velocity at REFERENCE_HZ (a slower logger: a quarter of its rate), the slowest direction
(materials.flexural_group_velocity_mm_per_us; a starting value, not a measurement: the threshold onset catches
faster, higher-frequency content). A logger that stops sooner loses the far sensors' arrivals on drops far from
them: the core reads such a channel as dead or without an onset, though nothing is wrong with the disc.
"""

from __future__ import annotations

import numpy as np

REFERENCE_HZ = 10e3    # an impact's arrivals carry most of their energy at a few to some tens of kHz
# ... as a logger holds them: a low-rate logger's records carry nothing above its Nyquist frequency and little
# near it; its arrivals are read at most at this share of its rate (half the Nyquist: 5 kHz at 20 kHz)
LOGGER_BAND_SHARE = 0.25
GRID_MM = 5.0
ANGLES_DEG = np.arange(0.0, 180.0, 15.0)


def longest_path_difference_mm(rig) -> float:
    """max over the plate (a GRID_MM grid, edges included) of max_k d_k - min_k d_k."""
    gx = np.linspace(0.0, rig.plate_x_mm, max(2, int(np.ceil(rig.plate_x_mm / GRID_MM)) + 1))
    gy = np.linspace(0.0, rig.plate_y_mm, max(2, int(np.ceil(rig.plate_y_mm / GRID_MM)) + 1))
    x, y = np.meshgrid(gx, gy)
    d = np.stack([np.hypot(x - s.x_mm, y - s.y_mm) for s in rig.sensors])
    return float((d.max(axis=0) - d.min(axis=0)).max())


def reference_hz(fs_hz: float) -> float:
    """The frequency the record check reads the plate's velocity at: REFERENCE_HZ, or LOGGER_BAND_SHARE of the
    logger's rate where that is lower (a 20 kHz logger's arrivals are read at 5 kHz, where the plate's flexural
    waves are slower: the far arrivals come later)."""
    return float(min(REFERENCE_HZ, LOGGER_BAND_SHARE * float(fs_hz)))


def slowest_velocity_mm_per_us(rig) -> float:
    """The plate's Mindlin flexural group velocity at reference_hz(rig.fs_hz) (the table's typical values) in its
    slowest direction."""
    from .materials import flexural_group_velocity_mm_per_us, material_for_rig

    mat = material_for_rig(rig)
    f = reference_hz(rig.fs_hz)
    return min(flexural_group_velocity_mm_per_us(mat, rig.thickness_mm, rig.density_kg_m3, f, float(a))
               for a in ANGLES_DEG)


def window_check(rig, samples: int, first_arrival_samples: int | None) -> dict:
    """The record after the first arrival (ms; None when the first arrival is not known) against the span the
    far arrivals need (ms): `short` when the record stops before the farthest arrival may come."""
    from .signal import CORE_MAX_SAMPLES, record_start

    recorded = int(samples)
    samples = min(recorded, CORE_MAX_SAMPLES)   # the core reads CORE_MAX_SAMPLES of a longer record
    start = record_start(recorded, first_arrival_samples, rig.fs_hz)   # ... from here (signal.record_start)
    path_mm = longest_path_difference_mm(rig)
    v = slowest_velocity_mm_per_us(rig)
    needed_ms = path_mm / v * 1e-3
    after_ms = (None if first_arrival_samples is None
                else (start + samples - first_arrival_samples) / rig.fs_hz * 1e3)
    return {"after_first_arrival_ms": after_ms, "far_arrival_ms": needed_ms, "path_difference_mm": path_mm,
            "velocity_mm_per_us": v, "reference_hz": reference_hz(rig.fs_hz), "record_samples": recorded,
            "core_samples": samples, "core_start": start,
            "short": bool(after_ms is not None and after_ms < needed_ms)}


def window_text(check: dict) -> str:
    """One line for the user: the record after the first arrival and what the far arrivals need."""
    need = (f"the farthest arrival comes up to ~{check['far_arrival_ms']:.2f} ms after the first "
            f"({check['path_difference_mm']:.0f} mm of path difference at ~{check['velocity_mm_per_us']:.2f} mm/us, "
            f"the plate's flexural group velocity at {check['reference_hz'] / 1e3:g} kHz)")
    if check["after_first_arrival_ms"] is None:
        return f"record after the first arrival: unknown; {need}"
    text = f"record after the first arrival: {check['after_first_arrival_ms']:.2f} ms"
    if check.get("core_samples", 0) < check.get("record_samples", 0):
        a = int(check.get("core_start", 0))
        text += (f" (the signal core reads {check['core_samples']} of a record's {check['record_samples']} samples, "
                 f"{'its first' if a == 0 else f'from sample {a}'})")
    text += f"; {need}"
    if check["short"]:
        text += (": SHORT, drops far from a sensor may lose its arrival (read as a dead channel or no onset): "
                 "keep more samples after the hit (fewer before it, or a longer record)")
    return text


def warn_if_short(session):
    """Prints window_text as a warning when the session's record stops before the far arrivals; the session."""
    check = window_check(session.rig, int(session.adc.shape[2]), session.rig.pretrigger_samples)
    if check["short"]:
        print(f"warning: {window_text(check)}")
    return session
