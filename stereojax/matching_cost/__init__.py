"""The matching cost: how much a left pixel and a right pixel at disparity d differ.

``classical``: census (Hamming distance of census transforms) and SAD, full range or in per-pixel
bands. ``learned``: the paper's Siamese network (tower features once per image, the head at the
band's disparities). ``coarse``: the coarse pass at reduced resolution that sets the bands."""

from stereojax.matching_cost.classical import (INVALID_COST, band_cost, census_cost,
                                               census_transform, matching_cost, sad_cost)
from stereojax.matching_cost.coarse import band_offsets, coarse_config
from stereojax.matching_cost.learned import LearnedModel, learned_volume, tower_features

__all__ = [
    "INVALID_COST", "band_cost", "census_cost", "census_transform", "matching_cost", "sad_cost",
    "LearnedModel", "learned_volume", "tower_features", "band_offsets", "coarse_config"
]
