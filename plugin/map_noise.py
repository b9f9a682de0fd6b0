"""What a landmark map measures about its own noise, and the association parameters that follow from it (ours).

The search's tolerances are about noise: theta_eps / sigma about how far apart the same pair of landmarks can be in
two maps, theta_r about how much one object's size differs between them. The paper fixes them for 0.3-0.5 m drone
landmarks (eps 2 m, sigma 1 m, theta_r 0.2); a map from 2.5 m/px airborne imagery needs several times more
(NAIP: eps 10 m, sigma 5 m, theta_r 0.4 were sized by hand from the truth). Both follow from quantities one map
measures on itself, with no second map and no truth (`measure_map_noise`, written into run.json by `sosmatch map`):

- `ground_resolution_m`: metres per pixel at the landmarks (median depth / f over the observations);
- `residual_m`: the median reprojection residual of one observation, in metres on the ground (pixels x depth / f):
  how far one segment's centroid lies from its landmark: centroid jitter of the segmenter at its working
  resolution, pose noise, and for fused tracks the drift between passes;
- `size_log_std`: the median over landmarks of the standard deviation of ln(size) over their observations, each
  observation's size taken on the landmark's horizontal plane (`landmark_size.plane_covariances`): how much the
  segment of one object changes from view to view.

A landmark of another session is another draw of the same segmentation process, of an object that may have
changed meanwhile (season, water level, growth), so two maps disagree by more than one observation scatters. How
much more was measured on the synthetic cross-season pairs of the tuning worlds 5 and 11 (summer-winter on the
same path, crossing at 90 degrees, at 130 m, spring-autumn: BENCHMARKS.md, "Seasons, crossing flights and
altitude"): the pairwise distance mismatch of common landmarks reaches 2.0-4.6 x the per-observation residual at its
90th percentile (median 2.7), their size difference r reaches 1.5-3.3 x sqrt(s_A^2 + s_B^2) at its 80th (median
2.2). Hence (`derived_association_params`):

    sigma = 1.5 residual (the larger of the two maps'),   theta_eps = 2 sigma (the paper's ratio) = 3 residual,
    theta_r = 3 sqrt(s_A^2 + s_B^2)

On the 100 m synthetic maps (residual 0.9-1.0 m, s 0.08-0.09) this gives eps ~2.8 m, sigma ~1.4 m, theta_r
~0.35; at 130 m eps ~4 m; on the NAIP 2.5 m/px maps (residual 3.3-3.4 m, s 0.065) eps ~10 m, sigma ~5 m, theta_r
~0.28: the hand-sized aerial preset's tolerances, from the maps alone.

Windows and theta_S follow from the two maps' geometry at those tolerances (`derived_search_params`, the chance
model of `association.window_chance`): maps so sparse for their tolerance that a configured window holds far
fewer than one chance-consistent association per transform get longer windows, and theta_S above their largest
chance set (NAIP: 200 landmarks, theta_S 10, the aerial preset's hand-sized values); survey maps keep the
configured 50 / 10 / 6.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

from .geometry import Camera
from .landmark_size import plane_covariances
from .params import AssociationParams

SIGMA_PER_RESIDUAL = 1.5  # sigma of the affinity per metre of per-observation residual (eps = 2 sigma)
SIZE_GATE_PER_SPREAD = 3.0  # theta_r per unit of sqrt(s_A^2 + s_B^2)
MAX_FIGURE = 1000.0  # the largest noise figure in metres a map file may hold (`MapNoise.problem`)
MAX_SIZE_SPREAD = 10.0  # and the largest spread of ln size


@dataclass(frozen=True)
class MapNoise:
    """A map's own noise figures (module doc); NaN where the map has no landmarks."""

    ground_resolution_m: float
    residual_m: float
    size_log_std: float
    landmarks: int

    def to_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict) -> MapNoise:
        def num(key: str) -> float:
            value = data.get(key)
            return float("nan") if value is None else float(value)

        return cls(num("ground_resolution_m"), num("residual_m"), num("size_log_std"), int(data.get("landmarks", 0)))

    @classmethod
    def of_merged(cls, parts: list[MapNoise | None]) -> MapNoise | None:
        """The figures of a map merged from maps with these figures (None if any is unknown): each the largest
        of the parts' (a merged map scatters at least as much as its noisiest part, and its parts' frames were
        aligned with errors of their own), the landmarks summed."""
        known = [p for p in parts if p is not None]
        if not known or len(known) < len(parts):
            return None

        def largest(key: str) -> float:
            values = [getattr(p, key) for p in known if math.isfinite(getattr(p, key))]
            return max(values) if values else float("nan")

        return cls(largest("ground_resolution_m"), largest("residual_m"), largest("size_log_std"),
                   sum(p.landmarks for p in known))

    def problem(self) -> str | None:
        """What makes these figures impossible for a landmark map, or None: each NaN (unknown) or a non-negative
        number up to MAX_FIGURE (metres of ground; no imagery a landmark map is made from has kilometre pixels, and
        a spread of ln size of 10 is a factor of 20,000 between one object's views). The one check of every file
        that holds them (`.sosmap` version 2, run.json)."""
        figures = np.array([self.ground_resolution_m, self.residual_m, self.size_log_std], dtype=np.float64)
        limits = np.array([MAX_FIGURE, MAX_FIGURE, MAX_SIZE_SPREAD])
        known = ~np.isnan(figures)
        if np.any(~np.isfinite(figures[known])) or np.any(figures[known] < 0) or np.any(figures[known] > limits[known]):
            return (f"noise figures must be unknown or within [0, {MAX_FIGURE:g}] m (size spread [0, "
                    f"{MAX_SIZE_SPREAD:g}]): ground resolution {self.ground_resolution_m:g} m, residual "
                    f"{self.residual_m:g} m, size spread {self.size_log_std:g}")
        if not 0 <= self.landmarks < 2**32:
            return f"noise figures' landmark count {self.landmarks} is not a count"
        return None

    @property
    def usable(self) -> bool:
        return self.landmarks > 0 and all(math.isfinite(v) and v > 0 for v in (self.residual_m, self.size_log_std))


def measure_map_noise(camera: Camera, rotations_wc: np.ndarray, centers: np.ndarray, points: np.ndarray,
                      observations: list[np.ndarray], pixels: list[np.ndarray],
                      covariances_px: list[np.ndarray]) -> MapNoise:
    """The noise figures of a map: per landmark i, its point, observing keyframes `observations[i]` (n,) (indices
    into rotations_wc / centers, world_from_camera), the observed pixels (n, 2) and mask covariances (n, 2, 2)
    (pixels of the pinhole `camera`)."""
    gsd, residual, spread = [], [], []
    r_cw = np.transpose(np.asarray(rotations_wc, np.float64), (0, 2, 1))
    f = float(np.sqrt(camera.fx * camera.fy))
    for point, kf, px, cov in zip(points, observations, pixels, covariances_px):
        kf = np.asarray(kf, np.int64)
        p = np.einsum("nij,nj->ni", r_cw[kf], np.asarray(point, np.float64)[None] - centers[kf])
        depth = p[:, 2]
        uv = np.stack([camera.fx * p[:, 0] / depth + camera.cx, camera.fy * p[:, 1] / depth + camera.cy], 1)
        gsd.append(depth / f)
        residual.append(np.linalg.norm(uv - np.asarray(px, np.float64), axis=1) * depth / f)
        plane = plane_covariances(camera, np.asarray(rotations_wc)[kf], centers[kf], point, cov)
        h = np.sqrt(np.maximum(np.linalg.eigvalsh(plane)[:, 1], 1e-12))
        if len(h) >= 2:
            spread.append(float(np.std(np.log(h))))
    if not gsd:
        return MapNoise(float("nan"), float("nan"), float("nan"), 0)
    return MapNoise(float(np.median(np.concatenate(gsd))), float(np.median(np.concatenate(residual))),
                    float(np.median(spread)) if spread else float("nan"), len(gsd))


# the association settings `derived_association_params` replaces (theta_eps, sigma, theta_r)
DERIVED_TOLERANCES = ("distance_tolerance_m", "affinity_sigma_m", "max_size_difference")


def replaced_settings(configured: AssociationParams, used: AssociationParams, chosen: Collection[str]) -> str | None:
    """What a warning says when settings the user chose (`chosen`: dotted names, `config_io.chosen_settings`) among
    the tolerances derived from the maps (`configured` as given, `used` as derived) are not what the answer was
    searched and verified with, else None (rev56 D8: `--set association.distance_tolerance_m=5` was replaced by
    the derived 3.22 without a word); none when `association.derive_from_maps` is chosen too. A tighter value
    given runs only the first of two searches (`first_search_params`), the derived one verifies and answers after
    it; a looser one is not used at all."""
    if "association.derive_from_maps" in chosen:
        return None  # asked for (a `config dump` file names every setting): the derivation is what was chosen
    said = []
    for name in DERIVED_TOLERANCES:
        given, derived = getattr(configured, name), getattr(used, name)
        if f"association.{name}" in chosen and given != derived:
            said.append(f"association.{name}={given:g} " + (
                f"replaced by {derived:g} derived from the maps" if given > derived else
                f"searched first, then {derived:g} derived from the maps, which verifies the answer"))
    if not said:
        return None
    return "; ".join(said) + " (association.derive_from_maps): set association.derive_from_maps=false to keep yours"


def derived_association_params(base: AssociationParams, noise_a: MapNoise | None,
                               noise_b: MapNoise | None) -> AssociationParams:
    """The association parameters for two maps: with `base.derive_from_maps`, theta_eps, sigma and theta_r
    derived from the maps' noise (module doc); otherwise, or when either map has no usable noise figures (a bare
    .sosmap, a COLMAP model, an empty map), `base` unchanged. One function for every consumer (match, evaluate)."""
    if not base.derive_from_maps or noise_a is None or noise_b is None or not (noise_a.usable and noise_b.usable):
        return base
    # within the parameters' declared ranges (theta_eps <= 1000 m, theta_r <= 1: any size): maps that noisy
    # are searched at the widest tolerances the search accepts, not refused for a figure nobody set; and no
    # tighter than the figures' own resolution (sigma is kept in centimetres: below 5 mm it rounded to 0, which
    # the search refuses; a size gate under 1 % is below what one object's sizes repeat to in any map)
    sigma = min(max(SIGMA_PER_RESIDUAL * max(noise_a.residual_m, noise_b.residual_m), 0.01), 500.0)
    theta_r = min(max(SIZE_GATE_PER_SPREAD * math.hypot(noise_a.size_log_std, noise_b.size_log_std), 0.01), 1.0)
    return dataclasses.replace(base, affinity_sigma_m=round(sigma, 2), distance_tolerance_m=round(2.0 * sigma, 2),
                               max_size_difference=round(theta_r, 3))


def resolution_gap(noise_a: MapNoise | None, noise_b: MapNoise | None, size_gate: float) -> str | None:
    """Why two maps' landmarks may be other objects, when their ground resolutions (`MapNoise.ground_resolution_m`)
    differ by more than the size gate admits between two sizes (`association.gates.size_ratio` of the
    resolutions above `size_gate`, theta_r): a segment one working pixel across covers that much more ground in
    one map, so its segmenter merges what the other splits (nu57: 150 m against 60 m, 0.59 and 0.24 m per pixel,
    10 of 85 landmarks within 2 m of one of the other map). None: within the gate, or a figure unknown."""
    from .association.gates import size_ratio

    if noise_a is None or noise_b is None:
        return None
    ga, gb = noise_a.ground_resolution_m, noise_b.ground_resolution_m
    if not (ga > 0 and gb > 0):
        return None
    r = float(size_ratio(np.array([ga]), np.array([gb]))[0])
    if not r > size_gate:
        return None
    return (f"the maps were made at {ga:.2f} and {gb:.2f} m of ground per pixel (x{max(ga, gb) / min(ga, gb):.1f}: "
            f"flown at other heights, or with other lenses?), further apart than the size gate admits (r {r:.2f} > "
            f"theta_r {size_gate:.3g}): their segmenters see different objects, which alone can leave no match; "
            "match maps of similar ground resolution")


@dataclass(frozen=True)
class DerivedSearch:
    """The association parameters two maps get (`derived_search_params`) and what they were derived from."""

    params: AssociationParams
    record: dict  # match.json "search_mode" "derived": which values were derived, and from what
    # the first of the two searches (`first_search_params`; `match_answer.match_maps`' `first_try`), None when one
    # search is enough
    first_try: AssociationParams | None = None
    # a last search at wider windows when the derived one is refused (`window_chance`, "Wider windows";
    # `match_maps`' `wider_try`), None when the windows were not grown or a wider one is not affordable
    wider_try: AssociationParams | None = None
    # the search near the maps' georeference, when the chance model within that prior lowers theta_S
    # (`window_chance.DerivedWindows.near_params`; `match_maps`' `near_try`); None: the derived parameters
    near_try: AssociationParams | None = None


def derived_search_params(base: AssociationParams, noise_a: MapNoise | None, noise_b: MapNoise | None,
                          points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                          sizes_b: np.ndarray | None) -> DerivedSearch:
    """Every association parameter that follows from the two maps, for every consumer (match, evaluate): the
    tolerances from their noise (`derived_association_params`), then, at those tolerances, the windows and theta_S
    from their geometry (`association.window_chance.derived_windows`). Both only with `base.derive_from_maps` and
    both maps' noise figures; otherwise `base` unchanged (a .sosmap file or COLMAP model keeps the configured
    search). `first_try` is the first of the two searches every consumer runs (`first_search_params`), `wider_try`
    the last one after a refusal, at wider windows."""
    tolerances = derived_association_params(base, noise_a, noise_b)
    if tolerances is base:
        return DerivedSearch(base, {"tolerances": "configured", "windows": "configured"})
    from .association.window_chance import derived_windows

    record: dict = {"tolerances": {"from": "map noise (residual_m, size_log_std)",
                                   **{name: getattr(tolerances, name) for name in DERIVED_TOLERANCES},
                                   # what they replaced: a refusal of this output names a change of them (rev56 D8)
                                   "configured": {name: getattr(base, name) for name in DERIVED_TOLERANCES}}}
    windows = derived_windows(points_a, sizes_a, points_b, sizes_b, tolerances)
    record["windows"] = {"from": "landmark density, size-gate fraction and theta_eps (chance model, "
                                 "association.window_chance)", **windows.to_dict()}
    return DerivedSearch(windows.params, record, first_search_params(base, windows.params), windows.wider_params,
                         windows.near_params)


def first_search_params(configured: AssociationParams, derived: AssociationParams) -> AssociationParams | None:
    """The tolerances of the first of two searches (`match_answer.match_maps`' `first_try`): the tighter of the
    configured and the derived theta_eps, sigma and theta_r, the rest as derived. The derived ones allow for what
    changes between two sessions (season, growth), which the maps cannot measure and two sessions of one season
    do not need; looser tolerances multiply the chance-consistent pairs until nothing is pruned (the evaluation
    suite's summer pairs: 0.26 -> 6.4 s of CPU, BENCHMARKS.md). Likewise the configured windows and theta_S:
    longer derived windows (`association.window_chance`) allow for few repeating landmarks, which the maps cannot
    measure either, and cost more where the configured windows already find the answer (the demo: 0.056 -> 0.096 s
    CPU). None when the derived ones are nowhere looser (derivation off, or maps less noisy than the configured
    values allow, and the configured windows kept): one search is enough."""
    first = dataclasses.replace(
        derived, distance_tolerance_m=min(configured.distance_tolerance_m, derived.distance_tolerance_m),
        affinity_sigma_m=min(configured.affinity_sigma_m, derived.affinity_sigma_m),
        max_size_difference=min(configured.max_size_difference, derived.max_size_difference),
        window_length=configured.window_length, window_stride=configured.window_stride,
        min_associations=configured.min_associations)
    return None if first == derived else first
