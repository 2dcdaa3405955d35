"""Typed exceptions raised at the public boundaries of stereojax.

Every user mistake (bad file, bad shape, bad option) raises a subclass of
:class:`StereoError` whose message says what was expected and what was found.
The CLI maps each class to a documented exit code and prints one line.
"""


def wxh(shape) -> str:
    """An image size as messages write it, width by height: ``(375, 1242)`` -> ``"1242x375"``;
    a third axis (channels) follows, ``(375, 1242, 3)`` -> ``"1242x375x3"``."""
    dims = [int(n) for n in shape]
    return "x".join(map(str, dims[1::-1] + dims[2:])) if len(dims) >= 2 else "x".join(map(str, dims))


class StereoError(Exception):
    """Base class of all errors stereojax raises on bad input."""

    exit_code = 1


class StereoInputError(StereoError, ValueError):
    """An image, a pair of images, a ground-truth map or a data folder is unusable."""

    exit_code = 2


class ConfigError(StereoError, ValueError):
    """A configuration value is out of range or contradicts another value."""

    exit_code = 3


class CheckpointError(StereoError):
    """A checkpoint is missing, corrupt, or from another architecture."""

    exit_code = 4


class OutputError(StereoError, OSError):
    """An output file or folder cannot be written."""

    exit_code = 5


class OutputBusyError(OutputError):
    """Another live process holds the output folder's lock (a batch ``predict`` or an
    ``evaluate`` writing into the same ``--out``); nothing was written."""

    exit_code = 8


class ClusterError(StereoError):
    """A Ray cluster (``predict --ray``) cannot be reached or used; nothing was computed."""

    exit_code = 9


class MemoryBudgetError(StereoError, MemoryError):
    """The chain's cost volumes would not fit in the memory limit; refused before allocating.

    The message names the estimate, the limit and where it comes from, and what to do
    (a smaller maximum disparity, a downscaled pair, or ``STEREOJAX_MEMORY_LIMIT_GB``).
    """

    exit_code = 6


class InputWarning(UserWarning):
    """An input was accepted after a conversion the caller may not expect (e.g. a colour
    image paired with a grey one: both are converted to grey)."""


class TrainingError(StereoError):
    """Training cannot go on (e.g. the loss became NaN); the last good checkpoint is kept."""

    exit_code = 7
