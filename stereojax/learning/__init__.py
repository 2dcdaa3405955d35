"""Learning: patch sampling, the losses, the training loop and dense distillation.

It uses the chain, the matching cost and the models, and never imports :mod:`stereojax.inference`
or :mod:`stereojax.app` (``tests/system/test_layers.py`` checks it). Import the modules themselves, e.g.
``from stereojax.learning.train import TrainConfig, train``."""

