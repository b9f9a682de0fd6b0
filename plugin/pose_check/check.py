"""The check itself: which pairs (from the capture order, bounded), their pose-free matches judged by the poses
(`PairCheck`), and the figures of the whole flight (`PoseCheck`)."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..fixed_in_frame import FixedInFrame, learn_fixed_in_frame
from ..geometry import SAME_POSITION, Camera, Poses
from ..image_matching import OrbFeatures, ratio_matches
from ..params import PoseCheckParams
from ..pass_heights import flight_passes
from .gps import GpsComparison
from .matches import PairMatches, match_pair
from .swaps import Exchange, exchanged_cameras
from .systematic import SystematicErrors, fit_systematic_errors, lag_along_track_m, pair_sampson_px, track_in_camera
from .two_view import ray_angles, relative_poses, triangulation_depths

# A pair tells the direction of motion (the sign of its depths) and the flying height only when its parallax rises
# clearly above the pixel noise of one match: at 2 noises a match's depth has the wrong sign with odds of 2 %, and a
# pair's verdict is the majority of its 30-200 inliers (clear: in_front 0.95-1.0 on true poses, 0.0-0.05 with a
# heading fault, on 1.2 m steps); its median depth is that of its median parallax (depth falls monotonically with
# parallax). The parallax counted is the smaller of what the matches show and what the poses' baseline gives: the
# poses' attitude noise fakes a parallax the first cannot tell from a baseline. Without parallax the depths are
# noise: a hover's images (baselines of the poses' own noise, 0.2 m) were read as a pass flown backwards, and a
# flight of 0.5 m steps measured 81 m of flying height for 100 m (the nu22 sweep).
MIN_PARALLAX_NOISES = 2.0


@dataclass(frozen=True)
class PairCheck:
    """One pair: its pose-free matches judged by the poses (pixels of the ideal pinhole image, full size)."""

    a: int
    b: int
    kind: str  # "next" (consecutive images), "wide" (k images apart), "cross" (another part of the flight)
    matches: int
    inliers: int
    flow_px: float  # median image motion of the inliers
    epipolar_px: float  # median Sampson distance under the poses
    epipolar_p90_px: float
    epipolar_fit_px: float  # the same after the systematic errors were taken off the poses
    in_front: float  # share of inliers the poses triangulate in front of both cameras
    depth_m: float  # median depth of the inliers in camera a (the poses' triangulation): the flying height
    # the smaller of the matches' median parallax (the rotation taken off) and the parallax the poses' baseline
    # gives at the flying height, px
    parallax_px: float = float("nan")
    sees_direction: bool = True  # parallax_px >= MIN_PARALLAX_NOISES pixel noises: its depths' signs mean something
    beyond_gate: float = float("nan")  # share of its inliers further off their epipolar line than the tracker's gate

    def reversed(self, gate_px: float) -> bool:
        """The matches fit the poses' epipolar geometry but lie behind the cameras: the motion is reversed. Judged
        only on a pair whose parallax tells the direction (`sees_direction`): without a baseline every essential
        matrix fits the matches and the depths' signs are noise."""
        return self.sees_direction and self.in_front < 0.5 and self.epipolar_px <= gate_px

    def to_list(self) -> list:
        return [self.a, self.b, self.kind, self.inliers, round(self.epipolar_px, 3), round(self.epipolar_fit_px, 3),
                round(self.in_front, 3), round(self.parallax_px, 2) if np.isfinite(self.parallax_px) else None]



@dataclass
class PoseCheck:
    """How the poses explain the pose-free matches of a subsample of image pairs (module doc)."""

    images: int
    pairs_tried: int
    pairs_checked: int
    focal_px: float
    gate_px: float  # the tracker's epipolar gate for this image (the scale of "far off")
    flying_height_m: float
    epipolar_p50_px: float  # median over pairs of each pair's median Sampson distance
    epipolar_p90_px: float
    epipolar_fit_p50_px: float  # after the systematic errors are taken off
    share_beyond_gate: float  # pairs whose median match is further off its epipolar line than the gate
    reversed_pairs: int
    reversed_passes: list[dict] = field(default_factory=list)  # passes whose checked pairs are mostly reversed
    systematic: SystematicErrors = field(default_factory=SystematicErrors)
    wide_offset: int = 1
    pairs: list[PairCheck] = field(default_factory=list)
    # the limit the systematic fit's condition index was held to (`PoseCheckParams.max_condition_index`)
    max_condition_index: float = float("inf")
    # the significance level the fit had to reach and the share of the misfit it had to explain
    # (`PoseCheckParams.systematic_significance`, `min_systematic_share`)
    systematic_significance: float = 1.0
    min_systematic_share: float = 0.0
    # the warning limit of the shared attitude error (`PoseCheckParams.warn_attitude_bias_deg`): the attitude is
    # checked only where the fit pins it to half of it (`attitude_checked`)
    warn_attitude_bias_deg: float = float("inf")
    # the share of the GPS fixes a camera path must follow for its scale to be judged (`min_gps_agreement`)
    min_gps_agreement: float = 0.5
    # the camera centres against the images' own GPS fixes (None: too few fixes, or not compared)
    gps: GpsComparison | None = None
    # the flight direction in the camera frame (`systematic.track_in_camera`): to name an attitude bias that a
    # lag along the track would give as well
    track_camera: tuple[float, float, float] = (float("nan"),) * 3
    # regions fixed in the image frame whose matches were left out (`plugin.fixed_in_frame`): boxes (x0, x1, y0, y1)
    # in full-size pixels, and the line that names them ('' when none)
    fixed_in_frame: list[tuple[int, int, int, int]] = field(default_factory=list)
    fixed_in_frame_text: str = ""
    # a pair fails against its cameras beyond max(camera_median_factor x the median pair error, camera_gate_fraction
    # x the gate) (`camera_limit_px`; `PoseCheckParams`)
    camera_median_factor: float = 10.0
    camera_gate_fraction: float = 0.5
    # cameras whose poses fit the images exchanged (`swaps.exchanged_cameras`)
    exchanges: list[Exchange] = field(default_factory=list)

    @property
    def camera_limit_px(self) -> float:
        """The pair error beyond which a pair counts against its cameras (`verdict.wrong_cameras`)."""
        return camera_limit_px(self.epipolar_p50_px, self.gate_px, self.camera_median_factor,
                               self.camera_gate_fraction)

    @property
    def matches_beyond_gate(self) -> float:
        """The share of all checked pairs' inlier matches (true correspondences: they fit a fundamental matrix)
        that the poses put further off their epipolar line than the tracker's gate: the share of true tracks the
        tracker would lose on these poses. NaN without checked pairs or the figure."""
        known = [(p.inliers, p.beyond_gate) for p in self.pairs if np.isfinite(p.beyond_gate)]
        if not known:
            return float("nan")
        weights, shares = np.array(known, np.float64).T
        return float(np.sum(weights * shares) / max(np.sum(weights), 1.0))

    @property
    def lag_along_track_m(self) -> float:
        """The lag along the track the images cannot tell from the attitude bias (`systematic.lag_along_track_m`;
        NaN when the bias is no pitch along the flight direction)."""
        return lag_along_track_m(self.systematic, np.asarray(self.track_camera), self.flying_height_m)

    @property
    def systematic_separable(self) -> bool:
        """Whether the flight's geometry tells the height drift, the tilt of the heights and a shared attitude
        error apart (`SystematicErrors.condition_index` within the limit): only then are they judged or reported."""
        return not self.systematic.condition_index > self.max_condition_index

    @property
    def systematic_explains(self) -> bool:
        """Whether the fitted systematic errors explain the pairs significantly better than the poses as given
        (`SystematicErrors.explained_p` below the level) and are most of their misfit (`explained_share`):
        otherwise the fit only shapes the poses' random errors into parameters (which may then be large) and is
        neither judged nor reported as a measurement."""
        s = self.systematic
        return not (s.explained_p > self.systematic_significance or s.explained_share < self.min_systematic_share)

    @property
    def systematic_significant(self) -> bool:
        """Whether the fitted systematic errors explain the pairs significantly better than the poses as given
        (`SystematicErrors.explained_p` at most the level): otherwise the fit's figures are no measurement and are
        neither quoted nor written as one (nu57: "they read 18.8 deg" of a fit at F 1.3, p 0.27)."""
        return bool(self.systematic.explained_p <= self.systematic_significance)

    @property
    def attitude_checked(self) -> bool:
        """Whether the checked pairs pin the attitude error shared by all cameras finely enough to see one at its
        warning limit: its standard deviation at most half that limit (a warning needs the error beyond the limit by
        two of them, so the errors warned about start at twice the limit at most). An oblique camera (30-35 deg
        forward) matches only consecutive images along the track (not another flight line, which looks at other
        ground, nor images several apart, whose perspective differs too much), and those short baselines measure
        the pitch only as well as the poses' random height errors allow: +-2-4 deg on correct EKF poses, so a 5-10
        deg pitch error was read as 4.3 +- 1.6 and 9.2 +- 3.1 deg and neither was warned (the 51st new-user sweep;
        nadir flights +-0.1-0.4 deg). Unknown (NaN) counts as checked: a fit without figures says so itself. An
        error the fit explains and finds beyond the warning limit by two of its standard deviations is checked too,
        however loosely pinned: it was judged, and found wrong (rev41: the line said "not checked" beside the
        warning or refusal of a 10-30 deg pitch error)."""
        s = self.systematic
        if not s.attitude_bias_sigma_deg > 0.5 * self.warn_attitude_bias_deg:
            return True
        return self.systematic_explains and beyond(s.attitude_bias_deg, s.attitude_bias_sigma_deg,
                                                   self.warn_attitude_bias_deg)

    @property
    def epipolar_p50_deg(self) -> float:
        return float(np.degrees(self.epipolar_p50_px / self.focal_px)) if self.focal_px > 0 else float("nan")

    def to_dict(self, names: list[str] | None = None) -> dict:
        def num(v: float) -> float | None:
            return round(float(v), 4) if np.isfinite(v) else None

        s = self.systematic
        # a fit no better than the random errors measured nothing: its values are left out (null), their sigmas kept
        fit = num if self.systematic_significant else (lambda v: None)
        out = {
            "images": self.images, "pairs_tried": self.pairs_tried, "pairs_checked": self.pairs_checked,
            "wide_offset": self.wide_offset, "focal_px": num(self.focal_px), "gate_px": num(self.gate_px),
            "flying_height_m": num(self.flying_height_m), "epipolar_p50_px": num(self.epipolar_p50_px),
            "epipolar_p90_px": num(self.epipolar_p90_px), "epipolar_p50_deg": num(self.epipolar_p50_deg),
            "epipolar_fit_p50_px": num(self.epipolar_fit_p50_px), "share_beyond_gate": num(self.share_beyond_gate),
            "matches_beyond_gate": num(self.matches_beyond_gate),
            "reversed_pairs": self.reversed_pairs, "reversed_passes": self.reversed_passes,
            "height_drift_m": fit(s.height_drift_m), "height_drift_sigma_m": num(s.height_drift_sigma_m),
            "height_tilt_deg": fit(s.height_tilt_deg), "height_tilt_sigma_deg": num(s.height_tilt_sigma_deg),
            "height_tilt_azimuth_deg": fit(s.height_tilt_azimuth_deg),
            "attitude_bias_deg": fit(s.attitude_bias_deg), "attitude_bias_sigma_deg": num(s.attitude_bias_sigma_deg),
            "attitude_bias_axis": [fit(v) for v in s.attitude_bias_axis],
            # false: the fit is no better than the poses' random errors, and its values above are null
            "systematic_significant": self.systematic_significant,
            # whether the pairs judged the shared attitude (`attitude_checked`): "ok" alone cannot say (rev41)
            "attitude_checked": self.attitude_checked,
            "systematic_condition_index": num(s.condition_index),
            "systematic_f": num(s.explained_f), "systematic_p": num(s.explained_p),
            "systematic_share": num(s.explained_share),
            "pairs_columns": ["a", "b", "kind", "inliers", "epipolar_px", "epipolar_fit_px", "in_front",
                              "parallax_px"],
            "pairs": [p.to_list() for p in self.pairs],
            "gps": self.gps.to_dict() if self.gps is not None else None,
            "fixed_in_frame_px": [list(b) for b in self.fixed_in_frame],
            "exchanges": [e.to_dict(names) for e in self.exchanges],
        }
        if names is not None:
            out["images_checked"] = sorted({names[i] for p in self.pairs for i in (p.a, p.b)})
        return out

    def line(self) -> str:
        """A short summary for the map's one-line report."""
        s = self.systematic
        text = f"poses vs images: epipolar {self.epipolar_p50_px:.1f} px ({self.pairs_checked} pairs), "
        if not self.pairs_checked:
            text = f"poses vs images: no pair of {self.pairs_tried} matched"
        elif not self.systematic_separable:  # the fit's figures mean nothing here (one straight line): do not print
            text += f"height drift and tilt not separable on this flight (condition index {s.condition_text})"
        elif not self.systematic_significant:  # nor here: no better than random errors would
            text += (f"no systematic error stands out of the random ones (F {_fmt(s.explained_f, '.1f')}, "
                     f"{_fmt(100 * s.explained_share, '.0f')} % of the misfit)")
        elif not self.systematic_explains:
            # significant, but too small a share to be told from the random errors' structure (correct EKF poses
            # do this too, so it is not judged); saying "nothing stands out" here contradicted a 14.6 +- 0.9 deg
            # tilt of a real fault (the 28th new-user sweep), so the fit's clearest term is named, unjudged
            text += (f"a systematic error is significant (F {_fmt(s.explained_f, '.1f')}) but explains only "
                     f"{_fmt(100 * s.explained_share, '.0f')} % of the misfit (under "
                     f"{100 * self.min_systematic_share:.0f} %), not judged; clearest: {_clearest_term(s)}")
        else:
            text += f"height drift {_fmt(s.height_drift_m, '+.1f')} m, tilt {_fmt(s.height_tilt_deg, '.1f')} deg"
        if self.pairs_checked and self.systematic_separable and not self.attitude_checked:
            # "nothing stands out" read as "the attitude was checked and found right" on an oblique flight whose
            # pitch the pairs cannot see (nu51): said, with how loosely the pairs pin it
            text += (f"; shared attitude not checked (the pairs pin it only to "
                     f"+-{self.systematic.attitude_bias_sigma_deg:.1f} deg)")
        text += f", {self.reversed_pairs} reversed" if self.reversed_pairs else ""
        if self.gps is not None and self.gps.follows(self.min_gps_agreement):
            text += f"; lengths {self.gps.scale_text}x the images' GPS ({self.gps.fixes} fixes)"
        elif self.gps is not None:  # its scale is no measurement (`verdict.judge_gps`), for the reason it names
            g = self.gps
            text += (f"; the flight spans too little against its GPS's jitter ({g.fix_noise_m:.1f} m) to check its "
                     "lengths" if g.too_small else
                     f"; lengths not checked (the path follows the images' GPS track, but only {g.inliers} of "
                     f"{g.fixes} fixes lie within its noise)" if g.explained >= self.min_gps_agreement else
                     "; lengths not checked (the path does not follow the images' GPS)")
        if self.fixed_in_frame_text:
            text += f"; {self.fixed_in_frame_text}"
        return text


def _clearest_term(s: SystematicErrors) -> str:
    """The fitted systematic term furthest from zero in its own standard deviations, with value and sigma."""
    terms = [(s.height_drift_m, s.height_drift_sigma_m, "height drift {v:+.1f} m (+-{e:.1f})"),
             (s.height_tilt_deg, s.height_tilt_sigma_deg, "height tilt {v:.1f} deg (+-{e:.1f})"),
             (s.attitude_bias_deg, s.attitude_bias_sigma_deg, "attitude {v:.1f} deg (+-{e:.1f})")]
    known = [(abs(v) / e, text.format(v=v, e=e)) for v, e, text in terms if np.isfinite(v) and np.isfinite(e) and e > 0]
    return max(known)[1] if known else "n/a"


def _fmt(v: float, spec: str) -> str:
    return format(v, spec) if np.isfinite(v) else "n/a"


def anchor_images(n: int, max_anchors: int) -> np.ndarray:
    """Up to `max_anchors` images spread evenly over the capture order (each starts the pairs of its checks)."""
    if n < 2:
        return np.zeros(0, dtype=np.int64)
    return np.unique(np.linspace(0, n - 2, min(n - 1, max(1, max_anchors))).round().astype(np.int64))


def wide_offset(flows_px: list[float], short_side_px: float, target_shift: float, max_offset: int) -> int:
    """How many images apart a pair moves the image by `target_shift` of its shorter side, from the consecutive
    pairs' image motion: wider baselines see the direction of motion (and the heights) better."""
    if not flows_px:
        return 1
    flow = float(np.median(flows_px))
    if flow <= 0:
        return max_offset
    return int(np.clip(round(target_shift * short_side_px / flow), 1, max_offset))


def cross_partners(centers: np.ndarray, anchors: np.ndarray, min_gap: int, radius_m: float) -> list[tuple[int, int]]:
    """For each anchor, the image nearest to it (horizontal distance of the poses' centres) at least `min_gap`
    images away in the capture order, if within `radius_m`: another flight line over the same ground."""
    c = np.asarray(centers, np.float64)[:, :2]
    out = []
    for i in anchors:
        d = np.linalg.norm(c - c[i], axis=1)
        d[max(0, i - min_gap):i + min_gap + 1] = np.inf
        j = int(np.argmin(d))
        if np.isfinite(d[j]) and d[j] <= radius_m:
            out.append((int(min(i, j)), int(max(i, j))))
    return out


def check_poses(poses: Poses, camera: Camera, features: Callable[[int], OrbFeatures], params: PoseCheckParams,
                gate_px: float) -> PoseCheck:
    """Check `poses` (in capture order) against the images: `features(i)` gives image i's ORB features (the
    caller reads the file; called at most once per image, only for the images of the chosen pairs).

    Pairs: consecutive images from up to `max_pairs / 3` anchors spread over the flight; pairs `wide_offset`
    images apart, the offset chosen from the consecutive pairs' image motion; and per anchor the nearest image of
    another part of the flight that the poses say overlaps (half a footprint, the footprint estimated from the
    consecutive pairs' image motion and the poses' spacing). `gate_px` is the tracker's epipolar gate.
    """
    n = len(poses)
    focal = float(np.sqrt(camera.fx * camera.fy))
    noise_px = params.noise_px / _working_scale(camera, params)
    cache: dict[int, OrbFeatures] = {}

    def feat(i: int) -> OrbFeatures:
        if i not in cache:
            cache[i] = features(i)
        return cache[i]

    tried: set[tuple[int, int]] = set()
    found: dict[tuple[int, int], tuple[str, PairMatches]] = {}
    ratio: dict[tuple[int, int], np.ndarray] = {}  # the consecutive pairs' ratio matches, made once

    def attempt(a: int, b: int, kind: str) -> PairMatches | None:
        if (a, b) in tried or a == b:
            return found.get((a, b), ("", None))[1]
        tried.add((a, b))
        pm = match_pair(a, b, feat(a), feat(b), camera, params, fixed if fixed else None, ratio.get((a, b)))
        if pm is not None:
            found[(a, b)] = (kind, pm)
        return pm

    anchors = anchor_images(n, params.max_pairs // 3)
    # learned from the consecutive pairs before any pair is judged: every pair leaves their matches out
    fixed = _fixed_in_frame(anchors, feat, camera, params, ratio)
    fixed_figures = {"fixed_in_frame": fixed.boxes(1.0 / feat(int(anchors[0])).scale) if fixed else [],
                     "fixed_in_frame_text": fixed.describe(1.0 / feat(int(anchors[0])).scale) if fixed else ""}
    flows = [pm.flow_px for i in anchors if (pm := attempt(int(i), int(i) + 1, "next")) is not None]
    short = float(min(camera.width, camera.height))
    k = wide_offset(flows, short, params.wide_shift, params.max_wide_offset)
    if k > 1:
        for i in anchors:
            if i + k < n:
                attempt(int(i), int(i) + k, "wide")
    steps = np.linalg.norm(np.diff(poses.centers[:, :2], axis=0), axis=1)
    if flows and len(steps):
        # metres per pixel of image motion between consecutive images -> the footprint's shorter side
        footprint = short * float(np.median(steps)) / max(float(np.median(flows)), 1e-9)
        for a, b in cross_partners(poses.centers, anchors, 2 * k + 1, params.cross_radius * footprint):
            attempt(a, b, "cross")

    keys = sorted(found)
    kinds = [found[key][0] for key in keys]
    matched = [found[key][1] for key in keys]
    if not matched:
        return PoseCheck(n, len(tried), 0, focal, gate_px, float("nan"), float("nan"), float("nan"), float("nan"),
                         float("nan"), 0, **fixed_figures)
    rot, t = relative_poses(poses.rotations, poses.centers, np.array([p.a for p in matched]),
                            np.array([p.b for p in matched]))
    raw = np.split(pair_sampson_px(poses, matched, focal), np.cumsum([p.inliers for p in matched])[:-1])
    depth, front, measured = [], [], []
    for p, r_p, t_p in zip(matched, rot, t):
        d_a, d_b = triangulation_depths(p.x_a, p.x_b, r_p, t_p)
        ok = (d_a > 0) & (d_b > 0)
        front.append(float(np.mean(ok)))
        depth.append(float(np.median(d_a[ok])) if ok.any() else float("nan"))
        measured.append(float(np.median(ray_angles(p.x_a, p.x_b, r_p))) * focal)
    depth_a = np.array(depth)
    consecutive = [k == "next" for k in kinds]
    least = MIN_PARALLAX_NOISES * noise_px
    # the parallax the poses claim (their baseline at the flying height): a hover's pairs match with the parallax of
    # the poses' attitude noise, which the rotation-compensated rays cannot tell from a baseline; the flying height
    # is measured on the pairs with parallax by the matches, then again with both
    baselines = np.array([np.linalg.norm(poses.centers[p.b] - poses.centers[p.a]) for p in matched])
    parallax = np.array(measured)
    flying = flying_height(depth_a, parallax, consecutive, least)
    if np.isfinite(flying) and flying > 0:
        parallax = np.minimum(parallax, focal * baselines / flying)
        flying = flying_height(depth_a, parallax, consecutive, least)
    # a pair whose poses stand at one position (a repeated pose row, a copy of an image) has no epipolar geometry:
    # its distances are undefined (NaN), it constrains no systematic error, and in the fit it stood in as 1e3 px per
    # match that a drift "explained" by moving the two centres apart (nu49: F 2721, 99.7 % "explained", a drift
    # printed as measured). It is left out of the fit; the map's inputs name such images
    # (`map.inputs.warn_duplicate_images`)
    has_baseline = ~without_baseline(baselines)
    systematic = fit_systematic_errors(poses, [p for p, b in zip(matched, has_baseline) if b], focal, flying,
                                       noise_px)
    fitted = systematic.corrected(poses, flying)
    after = np.split(pair_sampson_px(fitted, matched, focal), np.cumsum([p.inliers for p in matched])[:-1])
    after = [f if b else np.full_like(f, np.nan) for f, b in zip(after, has_baseline)]  # nothing fitted there
    with warnings.catch_warnings():  # a pair without a baseline in the poses has only NaN distances: NaN, said
        warnings.simplefilter("ignore", RuntimeWarning)  # by the verdict, not by numpy's "All-NaN slice" on stderr
        checks = [PairCheck(p.a, p.b, kind, p.matches, p.inliers, p.flow_px, float(np.nanmedian(r)),
                            float(np.nanpercentile(r, 90)), float(np.nanmedian(f)), fr, d, float(par),
                            bool(par >= least), _share_beyond(r, gate_px))
                  for p, kind, r, f, fr, d, par in zip(matched, kinds, raw, after, front, depth, parallax)]
        med = np.array([c.epipolar_px for c in checks])
        fit_med = np.array([c.epipolar_fit_px for c in checks])
        p50, p90, fit_p50 = (float(np.nanmedian(med)), float(np.nanpercentile(med, 90)),
                             float(np.nanmedian(fit_med)))
    reversed_passes = _reversed_passes(checks, poses, gate_px)
    # the pair error is blind to the sign of a baseline: two consecutive cameras' poses exchanged pass it
    # (`swaps`); asked directly, the images say whether the poses fit better exchanged
    limit = camera_limit_px(p50, gate_px, params.camera_median_factor, params.camera_gate_fraction)
    exchanges = exchanged_cameras(poses, matched, med, np.array([c.in_front for c in checks]),
                                  np.array([c.sees_direction for c in checks]), focal, limit, p50)
    return PoseCheck(
        images=n, pairs_tried=len(tried), pairs_checked=len(checks), focal_px=focal, gate_px=gate_px,
        flying_height_m=flying, epipolar_p50_px=p50, epipolar_p90_px=p90, epipolar_fit_p50_px=fit_p50,
        share_beyond_gate=float(np.mean(med > gate_px)),
        reversed_pairs=sum(c.reversed(gate_px) for c in checks), reversed_passes=reversed_passes,
        systematic=systematic, wide_offset=k, pairs=checks, max_condition_index=params.max_condition_index,
        systematic_significance=params.systematic_significance, min_systematic_share=params.min_systematic_share,
        warn_attitude_bias_deg=params.warn_attitude_bias_deg, min_gps_agreement=params.min_gps_agreement,
        track_camera=tuple(float(v) for v in track_in_camera(poses)),
        camera_median_factor=params.camera_median_factor, camera_gate_fraction=params.camera_gate_fraction,
        exchanges=exchanges, **fixed_figures)


def camera_limit_px(flight_px: float, gate_px: float, median_factor: float, gate_fraction: float) -> float:
    """The pair error beyond which a pair counts against its cameras: `median_factor` times the flight's median
    pair error `flight_px`, at least `gate_fraction` of the tracker's gate (a floor for flights whose median sits at
    the feature noise; the gate scales with the image). Relative to the flight's own residuals, not to the gate
    alone: with tracking.epipolar_margin_px=40 a swapped camera's 48-72 px passed 2 x the gate unsaid (rev55)."""
    return float(max(median_factor * flight_px, gate_fraction * gate_px))


def beyond(value: float, sigma: float, limit: float) -> bool:
    """|value| exceeds `limit` by more than two standard deviations (False for NaN): the verdict's test of a
    systematic error (`verdict.judge_poses`), and what counts as an attitude judged however loosely pinned
    (`PoseCheck.attitude_checked`)."""
    if not (np.isfinite(value) and np.isfinite(limit)):
        return False
    return bool(abs(value) - 2.0 * (sigma if np.isfinite(sigma) else np.inf) > limit)


def without_baseline(baselines_m: np.ndarray) -> np.ndarray:
    """Which pairs' poses put both cameras at one position (boolean, per pair): a baseline within rounding of zero
    (`geometry.SAME_POSITION`: one position given to every image, read with 1e-9 m of rounding, was judged on those
    nanometres: "a heading 180 deg off", a 56 deg "height tilt") or of at most a millionth of the longest checked
    one (a hover's noise, 0.2 m on 1-10 m steps, is far above both and keeps its pairs, whose direction the check
    does not judge: `PairCheck.sees_direction`)."""
    b = np.asarray(baselines_m, np.float64)
    return b <= max(SAME_POSITION, 1e-6 * float(np.max(b, initial=0.0)))


def _share_beyond(distances_px: np.ndarray, gate_px: float) -> float:
    """The share of the finite distances beyond `gate_px` (NaN when none is finite: a pair without a baseline)."""
    finite = distances_px[np.isfinite(distances_px)]
    return float(np.mean(finite > gate_px)) if len(finite) else float("nan")


def _fixed_in_frame(anchors: np.ndarray, feat: Callable[[int], OrbFeatures], camera: Camera,
                    params: PoseCheckParams, ratio: dict[tuple[int, int], np.ndarray]) -> FixedInFrame:
    """The regions fixed in the image frame (`plugin.fixed_in_frame`), learned from the ratio matches of the
    anchors' consecutive pairs (kept in `ratio` for their own check), in pixels of the working size."""
    pairs = []
    for i in anchors:
        a, b = int(i), int(i) + 1
        fa, fb = feat(a), feat(b)
        m = ratio[(a, b)] = ratio_matches(fa.descriptors, fb.descriptors, params.ratio)
        pairs.append((fa.points[m[:, 0]], fb.points[m[:, 1]]))
    scale = feat(int(anchors[0])).scale if len(anchors) else 1.0
    return learn_fixed_in_frame(pairs, camera.width * scale, camera.height * scale)


def flying_height(depths_m: np.ndarray, parallax_px: np.ndarray, consecutive: list[bool], min_parallax_px: float
                  ) -> float:
    """The flying height: the median of the pairs' median depths, over the pairs whose parallax is at least
    `min_parallax_px` (their depths are unbiased); without such a pair, over the consecutive pairs (else all), as
    well as they can tell. NaN when no pair triangulated."""
    finite = np.isfinite(depths_m)
    if not finite.any():
        return float("nan")
    seen = finite & (np.asarray(parallax_px) >= min_parallax_px)
    nexts = finite & np.asarray(consecutive, dtype=bool)
    return float(np.median(depths_m[seen if seen.any() else nexts if nexts.any() else finite]))


def _working_scale(camera: Camera, params: PoseCheckParams) -> float:
    return min(1.0, params.max_image_side_px / max(camera.width, camera.height))


def _reversed_passes(checks: list[PairCheck], poses: Poses, gate_px: float) -> list[dict]:
    """Passes of the flight (`pass_heights.flight_passes`) most of whose checked pairs inside the pass (at least
    two) are reversed: the poses say those images moved the other way. Pairs without the parallax to tell the
    direction (`PairCheck.sees_direction`) do not vote either way."""
    passes = flight_passes(poses.centers)
    out = []
    for k in np.unique(passes):
        inside = [c for c in checks if passes[c.a] == k and passes[c.b] == k and c.sees_direction]
        bad = [c for c in inside if c.reversed(gate_px)]
        if len(bad) >= 2 and len(bad) > 0.5 * len(inside):
            members = np.flatnonzero(passes == k)
            out.append({"pass": int(k), "first": poses.names[members[0]], "last": poses.names[members[-1]],
                        "images": int(len(members)), "pairs": len(inside), "reversed": len(bad)})
    return out
