"""The signal layer: touch windows and subsampling (the compiled front end and its numpy
reference) and the plot of a recording. Builds on eskin.data.

``eskin.signal.preprocess`` is the preprocessing module, which is itself callable as the
``preprocess`` function.
"""

from . import preprocess
from .plotting import (
    plot_recording,
)
from .preprocess import (
    TouchDetector,
    TouchWindow,
    TouchWindows,
    WindowConfig,
    detect_touches,
    detect_windows,
    subsample,
    subsample_indices,
)

__all__ = [
    "TouchDetector",
    "TouchWindow",
    "TouchWindows",
    "WindowConfig",
    "detect_touches",
    "detect_windows",
    "plot_recording",
    "preprocess",
    "subsample",
    "subsample_indices",
]
