"""impactsense: impact localisation and energy classification on a PZT-instrumented plate.

The public API (README "Python API"): load_session, load_model, train, predict, evaluate, export_for_board
(impactsense.api) and the scikit-learn estimators CoreFeatures, ImpactLocaliser, EnergyClassifier
(impactsense.estimators). They are imported on first use, so `import impactsense` stays light.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("impactsense")  # pyproject.toml [project] version, the one source
except PackageNotFoundError:  # imported from a source tree that was never installed
    __version__ = "0+unknown"

_API = {"load_session": "api", "load_model": "api", "train": "api", "predict": "api", "evaluate": "api",
        "export_for_board": "api", "CoreFeatures": "estimators", "ImpactLocaliser": "estimators",
        "EnergyClassifier": "estimators"}
__all__ = ["__version__", *_API]


def __getattr__(name):
    if name in _API:
        import importlib

        value = getattr(importlib.import_module(f"{__name__}.{_API[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_API))
