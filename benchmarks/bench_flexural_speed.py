"""The plate's flexural group velocity the record check takes (`impactsense info`, record_window.py) against what
the session's picks travel at: the materials table's typical values through Kirchhoff's sqrt(omega) law (before)
and through the Mindlin relation (materials.flexural_group_velocity_mm_per_us, now), at record_window's
REFERENCE_HZ (a slower logger: reference_hz, a quarter of its rate) in the slowest direction, beside the travel fit's velocity (the core's threshold picks at the
rig's default onset threshold, the declared positions, travel.fit_travel).

    python3 benchmarks/bench_flexural_speed.py DATA [DATA ...]      (DATA: a session folder or `bundled`)
"""

from __future__ import annotations

import argparse
import math
import sys



def kirchhoff_mm_per_us(rig, freq_hz: float) -> float:
    """Kirchhoff's 2 (D(theta) / rho h)^(1/4) sqrt(omega), the slowest direction (the law used before)."""
    from impactsense.materials import material_for_rig
    from impactsense.record_window import ANGLES_DEG

    mat, h = material_for_rig(rig), rig.thickness_mm * 1e-3
    out = []
    for a in ANGLES_DEG:
        if mat.orthotropic:
            e1, e2, g12, nu12 = (mat.e1_pa.value, mat.e2_pa.value, mat.g12_pa.value, mat.nu12.value)
            q = 1.0 - nu12 * nu12 * e2 / e1
            t = math.radians(a - mat.axis_deg)
            c, s = math.cos(t), math.sin(t)
            modulus = e1 / q * c ** 4 + (2 * nu12 * e2 / q + 4 * g12) * c * c * s * s + e2 / q * s ** 4
        else:
            modulus = mat.e_pa.value / (1.0 - mat.nu.value ** 2)
        d = modulus * h ** 3 / 12.0
        out.append(2.0 * (d / (rig.density_kg_m3 * h)) ** 0.25 * math.sqrt(2 * math.pi * freq_hz) * 1e-3)
    return min(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="+")
    a = ap.parse_args(argv)
    from impactsense.data import load_session
    from impactsense.record_window import REFERENCE_HZ, reference_hz, slowest_velocity_mm_per_us
    from impactsense.signal import SignalConfig
    from impactsense.travel import fit_travel, metric_choice, picks

    print(f"{'session':28s} {'thick mm':>8s} {'Kirchhoff':>9s} {'Mindlin':>8s} {'picks':>6s}  (mm/us; table's values "
          f"at {REFERENCE_HZ / 1e3:g} kHz, a slower logger's at a quarter of its rate, slowest direction; picks: travel fit at the default threshold)")
    for path in a.data:
        s = load_session(path)
        toa, period = picks(s.adc, SignalConfig.for_rig(s.rig), with_period=True)
        aniso = metric_choice(s.rig)
        fit = fit_travel(toa, s.xy_mm, s.rig.sensor_xy_mm, aniso, period, s.rig.fs_hz)
        print(f"{path[-28:]:28s} {s.rig.thickness_mm:8.1f} {kirchhoff_mm_per_us(s.rig, reference_hz(s.rig.fs_hz)):9.3f} "
              f"{slowest_velocity_mm_per_us(s.rig):8.3f} {fit.velocity_mm_per_us:6.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
