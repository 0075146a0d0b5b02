"""impactsense: impact localisation and energy classification on a PZT-instrumented plate."""

__version__ = "0.1.0"
