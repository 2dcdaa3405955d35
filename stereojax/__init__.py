"""stereojax: learned (MC-CNN-style) and classical stereo matching in JAX.

Public API::

    import stereojax
    disp = stereojax.disparity(left, right, config=stereojax.preset("census", max_disp=228))
    predict = stereojax.Predictor(config, model)  # compiled once per size bucket, many frames
    inter = stereojax.stages(left, right)          # every intermediate result
"""

from stereojax.config import (AggregationConfig, CostConfig, RefineConfig, SGMConfig, StereoConfig,
                              preset)
from stereojax.errors import (CheckpointError, ConfigError, InputWarning, MemoryBudgetError,
                              OutputError, StereoError, StereoInputError)
from stereojax.inference.predictor import Cascade, Predictor, disparity, stages
from stereojax.models.registry import load_model

__all__ = [
    "Predictor", "disparity", "stages", "preset", "load_model", "Cascade",
    "StereoConfig", "CostConfig", "AggregationConfig", "SGMConfig", "RefineConfig",
    "StereoError", "StereoInputError", "ConfigError", "CheckpointError", "OutputError",
    "MemoryBudgetError", "InputWarning",
]
__version__ = "0.1.0"
