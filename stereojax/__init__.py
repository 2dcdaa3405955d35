"""stereojax: learned (MC-CNN-style) and classical stereo matching in JAX.

Public API::

    import stereojax
    disp = stereojax.disparity(left, right, config=stereojax.preset("census", max_disp=228))
    predict = stereojax.Predictor(config, model)  # compiled once per size bucket, many frames
    inter = stereojax.stages(left, right)          # every intermediate result
    rig, report = stereojax.calibrate("cal/left*.jpg", "cal/right*.jpg", (9, 6), 0.025)
    predict = stereojax.Predictor(config, model, rectifier=stereojax.Rectifier(rig))  # raw pairs in
"""

from stereojax.config import (AggregationConfig, CostConfig, RefineConfig, SGMConfig, StereoConfig,
                              preset)
from stereojax.errors import (CheckpointError, ConfigError, InputWarning, MemoryBudgetError,
                              OutputError, StereoError, StereoInputError)
from stereojax.inference.predictor import Cascade, Predictor, disparity, stages
from stereojax.inference.sequence import Sequence
from stereojax.models.registry import load_model
from stereojax.data.stereo_rig import Rectifier, StereoRig, calibrate, read_rig


def log_rerun(path, frames, serve: bool = False):
    """Log frames to a Rerun ``.rrd`` file and/or its web viewer (:func:`stereojax.data.rerun_log.log_rerun`;
    needs ``pip install "stereojax[viewer]"``)."""
    from stereojax.data.rerun_log import log_rerun as _log

    return _log(path, frames, serve)


__all__ = [
    "Predictor", "disparity", "stages", "preset", "load_model", "Cascade", "Sequence",
    "calibrate", "read_rig", "Rectifier", "StereoRig", "log_rerun",
    "StereoConfig", "CostConfig", "AggregationConfig", "SGMConfig", "RefineConfig",
    "StereoError", "StereoInputError", "ConfigError", "CheckpointError", "OutputError",
    "MemoryBudgetError", "InputWarning",
]
__version__ = "0.1.0"
