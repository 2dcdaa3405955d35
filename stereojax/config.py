"""Frozen, hashable configuration of every pipeline stage, with validation and JSON round-trip.

Configs are passed to jitted functions as static arguments, so they must be hashable
(frozen dataclasses of plain numbers and strings). Every cost the pipeline handles is
normalised to [0, 1] (census: fraction of differing bits; SAD: mean absolute grey
difference / 255; learned: 1 - similarity), so the penalties below live on one scale.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import numbers
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping

from stereojax.errors import ConfigError

COST_METHODS = ("census", "sad", "learned")


BORDERS = ("replicate", "worst", "neutral")


@dataclass(frozen=True)
class CostConfig:
    """Classical matching cost.

    method: "census" (Hamming distance of census transforms), "sad" (paper Eq. 3.1) or
      "learned" (the matching network; pass its weights as ``params``).
    census_radius: (ry, rx) half-sizes of the census window, e.g. (3, 4) is 7x9.
    sad_radius: half-size of the square SAD window.
    border: matches that leave the image (x - d < 0): "replicate" compares with the repeated
      first column of the other image, "worst" gives them the worst cost (see matching_cost/classical.py),
      "neutral" gives them halfway between the pixel's best and mean in-view cost, so that
      aggregation and SGM carry disparities in from the rest of the image (any cost method,
      :func:`stereojax.matching_cost.classical.neutral_border`).
    rows_per_tile: image rows per tile of the learned dense head (bounds its memory).
    candidates: learned dense head only: 0 = exact (every disparity); K > 0 = PRUNED mode
      (not exact; entries the head does not see get cost 1), see ``unsure_share``.
      The head runs on the K best disparities of the census candidate chain of every pixel.
    unsure_share, unsure_candidates: pruned mode, *adaptive*: this share of the pixels, those
      where the head finds the poorest best match among the K, also gets the next candidates,
      up to ``unsure_candidates`` in all (0 = off).
    candidate_cbca, candidate_p1, candidate_p2: the census candidate chain (census window
      ``census_radius``, the cross arms of ``cbca``, this many CBCA passes, the SGM settings of
      ``sgm`` with these penalties on the census cost scale).
    """

    method: str = "census"
    census_radius: tuple[int, int] = (3, 4)
    sad_radius: int = 2
    border: str = "replicate"
    rows_per_tile: int = 32
    candidates: int = 0
    unsure_share: float = 0.0
    unsure_candidates: int = 0
    candidate_cbca: int = 1
    candidate_p1: float = 0.45
    candidate_p2: float = 7.2

    def validate(self) -> None:
        if self.method not in COST_METHODS:
            raise ConfigError(f"cost.method must be one of {COST_METHODS}, got {self.method!r}")
        ry, rx = self.census_radius
        if ry < 1 or rx < 1 or (2 * ry + 1) * (2 * rx + 1) - 1 > 96:
            raise ConfigError(
                f"cost.census_radius must be >= 1 with at most 96 census bits, got {self.census_radius}")
        if self.border not in BORDERS:
            raise ConfigError(f"cost.border must be one of {BORDERS}, got {self.border!r}")
        if self.rows_per_tile < 1 or self.candidates < 0:
            raise ConfigError(f"cost.rows_per_tile must be >= 1 and cost.candidates >= 0, got "
                              f"{self.rows_per_tile}, {self.candidates}")
        if self.sad_radius < 0:
            raise ConfigError(f"cost.sad_radius must be >= 0, got {self.sad_radius}")
        if not 0.0 <= self.unsure_share <= 1.0 or self.unsure_candidates < 0 or self.candidate_cbca < 0:
            raise ConfigError("cost.unsure_share must be in [0, 1], cost.unsure_candidates and "
                              f"cost.candidate_cbca >= 0, got {self.unsure_share}, "
                              f"{self.unsure_candidates}, {self.candidate_cbca}")
        if not 0 <= self.candidate_p1 <= self.candidate_p2:
            raise ConfigError("need 0 <= cost.candidate_p1 <= cost.candidate_p2, got "
                              f"{self.candidate_p1}, {self.candidate_p2}")


@dataclass(frozen=True)
class AggregationConfig:
    """Cross-based cost aggregation (CBCA), as used by MC-CNN.

    tau: intensity threshold of the cross arms, in grey levels (0-255).
    arm_length: maximum arm length in pixels (each of the four arms).
    iterations_before / iterations_after: CBCA passes before and after SGM.
    """

    tau: float = 20.0
    arm_length: int = 5
    iterations_before: int = 1
    iterations_after: int = 0

    def validate(self) -> None:
        if self.tau <= 0:
            raise ConfigError(f"cbca.tau must be > 0 grey levels, got {self.tau}")
        if self.arm_length < 1:
            raise ConfigError(f"cbca.arm_length must be >= 1, got {self.arm_length}")
        if self.iterations_before < 0 or self.iterations_after < 0:
            raise ConfigError("cbca iterations must be >= 0, got "
                              f"{self.iterations_before}, {self.iterations_after}")


@dataclass(frozen=True)
class SGMConfig:
    """Semi-global matching.

    directions: 0 (off), 4 (horizontal + vertical) or 8 (plus diagonals).
    p1, p2: penalties for a disparity change of 1 and of more than 1 (cost units, costs in [0, 1]).
    adaptive: MC-CNN's gradient-dependent reduction: where the grey-level change along the
      path exceeds `grad_threshold` in the left image and in the right image at the
      matching pixel, penalties are divided by q2; where it exceeds it in one of the two,
      by q1. `vertical_factor` divides p1 on vertical paths (MC-CNN's alpha; 1 = off).
    """

    directions: int = 4
    p1: float = 0.45
    p2: float = 7.2
    adaptive: bool = True
    q1: float = 3.0
    q2: float = 6.0
    grad_threshold: float = 15.0
    vertical_factor: float = 1.0

    def validate(self) -> None:
        if self.directions not in (0, 4, 8):
            raise ConfigError(f"sgm.directions must be 0, 4 or 8, got {self.directions}")
        if self.p1 < 0 or self.p2 < 0:
            raise ConfigError(f"sgm penalties must be >= 0, got p1={self.p1}, p2={self.p2}")
        if self.p2 < self.p1:
            raise ConfigError(f"sgm.p2 must be >= sgm.p1, got p1={self.p1}, p2={self.p2}")
        if self.q1 < 1 or self.q2 < 1 or self.vertical_factor < 1:
            raise ConfigError("sgm.q1, sgm.q2 and sgm.vertical_factor must be >= 1, got "
                              f"{self.q1}, {self.q2}, {self.vertical_factor}")


@dataclass(frozen=True)
class RefineConfig:
    """Disparity refinement after winner-takes-all.

    lr_check: left-right consistency check with occlusion/mismatch labelling and filling.
    lr_tolerance: |d_left - d_right| allowed, in pixels.
    right_from_left: derive the right view's disparities from the left aggregated volume
      (C_R(x, d) = C_L(x + d, d), as in Hirschmueller 2008) instead of aggregating the right
      volume separately; about half the work.
    subpixel: parabola fit through the costs at d - 1, d, d + 1.
    median_size: odd window of the median filter (0 or 1 = off).
    bilateral_radius, bilateral_sigma_space, bilateral_sigma_range: joint bilateral filter of
      the disparity guided by the left grey image (radius 0 = off; sigma_range in grey levels).
      Off by default: on KITTI 2015 frames 000001-000019 (odd) it raised the > 3 px error
      (4.39 % -> 4.55 % with radius 2, sigma_range 3; 6.10 % -> 6.36 % at weaker penalties).
    texture_full, texture_noise: the confidence is scaled by the share of the census window's
      pixels that differ from the centre by more than ``texture_noise`` grey levels, divided by
      ``texture_full`` and capped at 1: where the window has nothing for the cost to work on
      (saturated sky, a white wall), SGM's smoothing gives a disparity but not a confident one
      (:func:`stereojax.validation.confidence_measure.texture_factor`). texture_full 0 = off.
      Chosen on KITTI 2015 training frames: the sparsification area unchanged (3.854 -> 3.857
      on 7 frames) and saturated textureless sky kept at confidence >= 0.3 from 59.7 % to 4.4 %.
    """

    lr_check: bool = True
    lr_tolerance: float = 1.0
    right_from_left: bool = True
    subpixel: bool = True
    median_size: int = 5
    bilateral_radius: int = 0
    bilateral_sigma_space: float = 1.7
    bilateral_sigma_range: float = 12.0
    texture_full: float = 0.25
    texture_noise: float = 2.0

    def validate(self) -> None:
        if not (self.texture_full >= 0 and self.texture_noise >= 0):
            raise ConfigError(f"refine.texture_full and texture_noise must be >= 0, got {self.texture_full}, "
                              f"{self.texture_noise}")
        if self.lr_tolerance < 0:
            raise ConfigError(f"refine.lr_tolerance must be >= 0, got {self.lr_tolerance}")
        if self.median_size < 0 or (self.median_size > 1 and self.median_size % 2 == 0):
            raise ConfigError(f"refine.median_size must be 0, 1 or odd, got {self.median_size}")
        if self.bilateral_radius < 0 or self.bilateral_sigma_space <= 0 or self.bilateral_sigma_range <= 0:
            raise ConfigError("refine bilateral radius must be >= 0 and sigmas > 0, got "
                              f"{self.bilateral_radius}, {self.bilateral_sigma_space}, "
                              f"{self.bilateral_sigma_range}")


@dataclass(frozen=True)
class BandConfig:
    """Per-pixel disparity bands set by a coarse pass (stereojax.matching_cost.coarse).

    width: K, the disparities every pixel's band holds; 0 (or >= max_disp) = the full range
      0 .. max_disp - 1 for every pixel (no coarse pass).
    scale: the coarse pass runs at 1/scale of the resolution (2 or 4), over the full range, with
      census, one CBCA pass and SGM (penalties p1, p2, census cost scale).
    radius: a pixel's band covers the min..max of the coarse disparities within this many
      coarse pixels, plus ``margin`` full-resolution pixels each side, when that fits in K
      (otherwise K centred on the pixel's own coarse disparity); ``unsure_radius`` replaces
      ``radius`` where the coarse left-right check fails.
    """

    width: int = 0
    scale: int = 2
    radius: int = 1
    unsure_radius: int = 3
    margin: int = 3
    p1: float = 0.45
    p2: float = 7.2

    def validate(self) -> None:
        if self.width < 0 or self.width == 1 or self.width == 2:
            raise ConfigError(f"band.width must be 0 (full range) or >= 3, got {self.width}")
        if self.scale not in (1, 2, 4):
            raise ConfigError(f"band.scale must be 1, 2 or 4, got {self.scale}")
        if self.radius < 0 or self.unsure_radius < 0 or self.margin < 0:
            raise ConfigError("band.radius, band.unsure_radius and band.margin must be >= 0, got "
                              f"{self.radius}, {self.unsure_radius}, {self.margin}")
        if not 0 <= self.p1 <= self.p2:
            raise ConfigError(f"need 0 <= band.p1 <= band.p2, got {self.p1}, {self.p2}")


@dataclass(frozen=True)
class StereoConfig:
    """The whole chain: matching cost -> CBCA -> SGM -> CBCA -> WTA -> LR check -> refinement."""

    max_disp: int = 228
    cost: CostConfig = field(default_factory=CostConfig)
    cbca: AggregationConfig = field(default_factory=AggregationConfig)
    sgm: SGMConfig = field(default_factory=SGMConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)
    band: BandConfig = field(default_factory=BandConfig)
    #: the kernels of the classical stages (stereojax.kernels): "auto" (native C++ on the CPU where
    #: they loaded, else JAX), "native" (an error where they did not load) or "xla" (JAX everywhere)
    kernels: str = "auto"

    @property
    def banded(self) -> bool:
        """Whether the chain runs on per-pixel bands (``band.width`` below ``max_disp``)."""
        return 0 < self.band.width < self.max_disp

    def validate(self) -> "StereoConfig":
        if not isinstance(self.max_disp, int) or isinstance(self.max_disp, bool) or self.max_disp <= 0:
            raise ConfigError(f"max_disp must be a positive integer, got {self.max_disp!r}")
        for sub in (self.cost, self.cbca, self.sgm, self.refine, self.band):
            sub.validate()
        if self.kernels not in ("auto", "native", "xla"):
            raise ConfigError(f"kernels must be 'auto', 'native' or 'xla', got {self.kernels!r}")
        if self.banded and not self.refine.right_from_left:
            raise ConfigError("band.width > 0 needs refine.right_from_left = true (the right view of a "
                              "banded chain is read from the left volume); set band.width = 0 for the "
                              "full-range chain")
        return self

    # ---- JSON round trip -------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "StereoConfig":
        return dataclass_from_dict(cls, data, "").validate()

    @classmethod
    def from_json(cls, text: str) -> "StereoConfig":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"config is not valid JSON: {exc}") from None
        if not isinstance(data, dict):
            raise ConfigError(f"config JSON must be an object, got {type(data).__name__}")
        return cls.from_dict(data)

    @classmethod
    def from_file(cls, path) -> "StereoConfig":
        """The config of a JSON file (``stereojax ... --config FILE``)."""
        try:
            text = Path(path).read_text()
        except OSError as exc:
            raise ConfigError(f"cannot read config file {path}: {exc.strerror}") from None
        return cls.from_json(text)

    def with_max_disp(self, max_disp: int) -> "StereoConfig":
        return replace(self, max_disp=_as_int(max_disp)).validate()


def dataclass_from_dict(cls, data: Mapping[str, Any], prefix: str = ""):
    """Build dataclass ``cls`` from a JSON mapping, recursing into dataclass-valued fields."""
    known = {f.name: f for f in fields(cls)}
    kwargs = {}
    for key, value in data.items():
        if key not in known:
            close = difflib.get_close_matches(key, list(known), n=1)
            hint = f"; did you mean '{prefix}{close[0]}'?" if close else f"; valid keys: {sorted(known)}"
            raise ConfigError(f"unknown config key '{prefix}{key}'{hint}")
        default = getattr(cls(), key)
        if dataclasses.is_dataclass(default):
            if not isinstance(value, Mapping):
                raise ConfigError(f"config key '{prefix}{key}' must be an object, got {value!r}")
            kwargs[key] = dataclass_from_dict(type(default), value, f"{prefix}{key}.")
        else:
            kwargs[key] = _coerce(value, default, f"{prefix}{key}")
    return cls(**kwargs)


def _coerce(value: Any, default: Any, name: str) -> Any:
    """Convert a JSON value to the type of the field's default (tuples, ints, floats, bools)."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"config key {name!r} must be true or false, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or int(value) != value:
            raise ConfigError(f"config key {name!r} must be an integer, got {value!r}")
        return int(value)
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"config key {name!r} must be a number, got {value!r}")
        return float(value)
    if isinstance(default, tuple):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"config key {name!r} must be a list, got {value!r}")
        if default and len(value) != len(default) and not name.endswith("widths"):
            raise ConfigError(f"config key {name!r} must be a list of {len(default)} values, got {value!r}")
        proto = default[0] if default else 0
        return tuple(_coerce(v, proto, name) for v in value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise ConfigError(f"config key {name!r} must be a string, got {value!r}")
        return value
    return value


def _as_int(value):
    """numpy integers (e.g. ``np.int64(16)``) -> int; anything else unchanged (validate() judges it)."""

    return int(value) if isinstance(value, numbers.Integral) and not isinstance(value, bool) else value


def preset(name: str, max_disp: int = 228) -> StereoConfig:
    """Named pipeline settings, tuned on KITTI 2015 training frames 000001-000019 (odd), see
    experiments/results/tuning.md: "census" (the defaults of StereoConfig) and "sad"."""
    max_disp = _as_int(max_disp)
    # per-pixel bands of 48 disparities from a half-resolution coarse pass, chosen on training
    # frames 000001-000019 (odd) by the rule of experiments/PROTOCOL.md ("Bands"):
    # experiments/results/band_search_census.md; band=BandConfig() is the full-range chain
    band = BandConfig(width=48, scale=2, radius=1, unsure_radius=3, margin=3)
    presets = {
        "census": StereoConfig(max_disp=max_disp, band=band),
        "sad": StereoConfig(
            max_disp=max_disp,
            cost=CostConfig(method="sad", sad_radius=3),
            sgm=SGMConfig(p1=0.2, p2=3.2), band=band,
        ),
    }
    # learned cost (1 - similarity): CBCA/SGM from a preliminary setting of 4 configurations on
    # training frames 000001 and 000003, see experiments/results/tuning.md. PRUNED mode by
    # default, adaptive: the head on the 6 best census candidates of every pixel and on 16 for
    # the 20 % of pixels where it finds the poorest match (8 head evaluations per pixel instead
    # of 228), chosen on training frames 000001-000011 (odd) from the schemes in
    # experiments/results/speed.md; cost.candidates=0 gives the exact head.
    presets["learned"] = StereoConfig(
        max_disp=max_disp,
        cost=CostConfig(method="learned", candidates=min(6, max_disp), unsure_share=0.2,
                        unsure_candidates=min(16, max_disp)),
        cbca=AggregationConfig(iterations_before=2), sgm=SGMConfig(p1=0.5, p2=8.0), band=band)
    if name not in presets:
        raise ConfigError(f"unknown preset {name!r}; choose one of {sorted(presets)}")
    return presets[name].validate()
