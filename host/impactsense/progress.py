"""Progress bars: drawn on a terminal only."""

from __future__ import annotations


def progress_bar(enabled: bool = True, **kwargs):
    """A tqdm bar (kwargs as tqdm's) drawn only when stderr is a terminal (tqdm's disable=None): a log file or a
    pipe never gets the carriage-return redraws. enabled=False: never drawn. The bar counts either way."""
    from tqdm import tqdm

    return tqdm(disable=None if enabled else True, **kwargs)
