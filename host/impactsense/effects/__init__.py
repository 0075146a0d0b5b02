"""The effect library: each effect a parameterised addition to the reference model with its own fit,
units and physical meaning (see `_base.Effect`). `EFFECTS` maps the names used in diagnose JSON to them."""

from .anisotropy import Anisotropy
from .channel_delay import ChannelDelay
from .channel_lowpass import ChannelLowpass
from .clipping import Clipping
from .damping import Damping
from .noise import Noise
from .sensor_gain import SensorGain
from .sensor_position import SensorPosition
from .wave_speed import WaveSpeed
from ._base import Effect, context

EFFECTS: dict[str, Effect] = {e.name: e for e in (
    ChannelDelay(), SensorGain(), SensorPosition(), ChannelLowpass(), WaveSpeed(), Damping(),
    Anisotropy(), Noise(), Clipping())}

__all__ = ["EFFECTS", "Effect", "context"]
