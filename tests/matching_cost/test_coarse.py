"""stereojax.matching_cost.coarse: the band rule (each pixel's band covers its coarse neighbourhood when it fits)."""

import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings, strategies as st

from stereojax.config import BandConfig
from stereojax.matching_cost import coarse


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.integers(8, 40), radius=st.integers(0, 2), margin=st.integers(0, 4))
def test_band_offsets_cover_the_coarse_neighbourhood_when_it_fits(seed, k, radius, margin):
    rng = np.random.default_rng(seed)
    d_max = 64
    disp = rng.integers(0, 32, (6, 8)).astype(np.int32)
    disp = np.clip(disp[:, :1] + rng.integers(-2, 3, disp.shape), 0, 31).astype(np.int32)
    sure = rng.random(disp.shape) < 0.8
    band = BandConfig(width=k, scale=2, radius=radius, unsure_radius=radius + 1, margin=margin)
    off = np.asarray(coarse.band_offsets(jnp.asarray(disp), jnp.asarray(sure), band, d_max, (12, 16)))
    assert off.min() >= 0 and off.max() <= d_max - k
    for y in range(12):
        for x in range(16):
            cy, cx = y // 2, x // 2
            r = radius if sure[cy, cx] else radius + 1
            win = disp[max(cy - r, 0): cy + r + 1, max(cx - r, 0): cx + r + 1]
            lo, hi = 2 * win.min() - margin, 2 * win.max() + 1 + margin
            lo_c, hi_c = max(lo, 0), min(hi, d_max - 1)
            if hi - lo + 1 <= k:
                assert off[y, x] <= lo_c and hi_c <= off[y, x] + k - 1
            else:   # centred on the pixel's own coarse disparity
                own = 2 * disp[cy, cx] + 1
                assert off[y, x] <= own <= off[y, x] + k - 1
