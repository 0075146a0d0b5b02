"""A disc's bond as a mechanical element: the strain a disc feels through a compliant adhesive layer.

The bond layer (shear stiffness k_b) lies in series with the disc's own in-plane stiffness k_d; the disc's loss
(its own and the adhesive fillet's viscosity, c) acts on the disc's extension u_d, its mass m on its acceleration:

    m u_d'' + c u_d' + (k_b + k_d) u_d = k_b u_p,        u_p the plate's surface extension under the disc,

so the disc's strain is the plate's through H(s) = k_b / (m s^2 + c s + k_b + k_d). While the disc's own
resonance lies far above the band (m (k_b + k_d) << c^2: the second pole c / m is hundreds of kHz for a PZT disc
of a fraction of a gram) H is first order: a gain g = k_b / (k_b + k_d) and a corner 1 / (2 pi tau), tau =
c / (k_b + k_d) (docs/method.md, "The discs' bond"). A weaker bond (smaller k_b / k_d) loses gain AND bandwidth:
the corner moves down with the same stiffness that sets the gain, by 1 + k_b / k_d.

The simulator applies H to the disc's continuous-time signal before the recorder samples it
(`simulate.analogue_fields`: the reciprocity run's hat load through the low-pass, `load_lowpass_s` of the run,
then the gain); the voltage is the disc's strain's linear functional, so filtering the strain is filtering it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError


@dataclass(frozen=True)
class DiscBond:
    """A disc's bond: stiffness_ratio k_b / k_d (> 0; infinite = rigid, no bond effect) and loss_time_s c / k_d
    (>= 0, s)."""

    stiffness_ratio: float
    loss_time_s: float

    def __post_init__(self):
        if not (self.stiffness_ratio > 0) or not (self.loss_time_s >= 0) or not math.isfinite(self.loss_time_s):
            raise ConfigError(f"a disc's bond needs stiffness_ratio > 0 and a finite loss_time_s >= 0, got "
                              f"{self.stiffness_ratio}, {self.loss_time_s}")

    @classmethod
    def from_gain_corner(cls, gain: float, corner_hz: float) -> "DiscBond":
        """The bond whose strain transfer has this gain (0 < gain < 1) and -3 dB corner (Hz)."""
        if not (0 < gain < 1) or not (corner_hz > 0):
            raise ConfigError(f"a disc's bond needs 0 < gain < 1 and corner_hz > 0, got {gain}, {corner_hz}")
        ratio = gain / (1.0 - gain)
        return cls(ratio, (1.0 + ratio) / (2 * math.pi * corner_hz))

    @property
    def gain(self) -> float:
        """k_b / (k_b + k_d): the strain transferred at low frequency."""
        return self.stiffness_ratio / (1.0 + self.stiffness_ratio)

    @property
    def time_constant_s(self) -> float:
        """c / (k_b + k_d)."""
        return self.loss_time_s / (1.0 + self.stiffness_ratio)

    @property
    def corner_hz(self) -> float:
        """The -3 dB corner (Hz; infinite without loss)."""
        tau = self.time_constant_s
        return math.inf if tau == 0 else 1.0 / (2 * math.pi * tau)

    def transfer(self, f_hz) -> np.ndarray:
        """H(j 2 pi f): the disc's strain over the plate's."""
        return self.gain / (1.0 + 2j * np.pi * np.asarray(f_hz, float) * self.time_constant_s)
