"""Does the camera's lens (cameras.txt) fit the images, given the fixed poses? (ours)

With the poses fixed, a landmark seen in many keyframes at different places in the image fixes the lens's
distortion: a wrong one bends each view's ray by an amount that depends on where in the image the object was
seen, so the rays of one object stop meeting, and the point where they meet best moves, mostly in height (the
rays of a nadir flight are steep). A survey flight's landmarks cross the whole image many times, so the map's own
observations measure the lens: refit its distortion (poses fixed, points free: `workflows.map.lens`) and compare
the two lenses by what they do to the map, the median height change of the landmarks re-triangulated with the
refit lens (`LensCheck.shift_m`).

The refit is also pulled by what is not the lens (a segment's centroid drifting as an object is seen from the
side, the tracker's pieces), and observations of one landmark are not independent, so a per-observation F-test
calls a correct lens wrong (the 100 degree synthetic lens, correct: F 25 on 1168 observations). Its significance
is measured on the landmarks instead: the shift is refit K times with one block of landmarks left out each time
(delete-a-group jackknife, blocks in landmark order = flight order, so neighbouring landmarks leave together) and
its standard error is their scatter (`jackknife_se`). A lens is called wrong when the shift is beyond
`QualityParams.lens_shift_margin` standard errors AND large for the map (`judge_lens`): a warning beyond
`warn_lens_height_shift` of the flying height, a refusal beyond `max_lens_height_shift`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import Camera

# the model the refit frees the distortion of, for a camera given without any: OPENCV (k1, k2, p1, p2) holds every
# pinhole's K unchanged; a camera with distortion parameters is refit in its own model
REFIT_MODEL = "OPENCV"
# the models whose distortion the map's observations fix: at most k1, k2 and tangential terms. Refit with 8 free
# terms (FULL_OPENCV) or a fisheye's k1..k4 on a 72-landmark map, even at the right lens, the terms ran away
# (k1 775, k3 289; a fisheye's k3 -13) and the heights moved 3.6-20 m at 2.5-4.6 standard errors: unchecked
CHECKED_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")


def refit_camera(camera: Camera) -> Camera | None:
    """The camera whose distortion the refit frees: `camera` itself when its model has distortion parameters, a
    pinhole camera (PINHOLE, SIMPLE_PINHOLE) as OPENCV with the same K and no distortion (so that a forgotten
    distortion can be found); None for a model outside CHECKED_MODELS."""
    if camera.model not in CHECKED_MODELS:
        return None
    if camera.extra:
        return camera
    return Camera(camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy, REFIT_MODEL,
                  (0.0, 0.0, 0.0, 0.0))


def lens_displacement_px(given: Camera, fitted: Camera, samples: int = 17) -> float:
    """The largest distance in pixels, over a `samples` x `samples` grid spanning the image, between where the two
    cameras see the same ray (given's pixel -> ray -> fitted's pixel): how far apart the lenses put the image's
    edge. NaN where neither lifts a pixel."""
    u = np.linspace(0.5, given.width - 0.5, samples)
    v = np.linspace(0.5, given.height - 0.5, samples)
    uv = np.stack(np.meshgrid(u, v), -1).reshape(-1, 2)
    moved = fitted.img_from_cam(given.cam_from_img(uv))
    d = np.linalg.norm(moved - uv, axis=1)
    return float(np.nanmax(d)) if np.isfinite(d).any() else float("nan")


def jackknife_se(leave_outs: np.ndarray) -> float:
    """Delete-a-group jackknife standard error of a statistic from its K values with one group left out each."""
    s = np.asarray(leave_outs, dtype=np.float64)
    s = s[np.isfinite(s)]
    k = len(s)
    if k < 2:
        return float("nan")
    return float(np.sqrt((k - 1) / k * np.sum((s - s.mean()) ** 2)))


def landmark_groups(n: int, groups: int) -> np.ndarray:
    """(n,) group index of each landmark: `groups` contiguous blocks in landmark order (flight order: landmarks
    that neighbour each other, and share their errors, leave the fit together)."""
    return np.minimum((np.arange(n) * groups) // max(n, 1), groups - 1)


@dataclass(frozen=True)
class LensCheck:
    """The lens refit on the map's observations, compared with the given one (module doc)."""

    camera_file: str  # where the given camera came from (named in the verdict)
    given: Camera
    fitted: Camera  # the given camera with the distortion the images fit (`refit_camera`'s model)
    shift_m: float  # median over landmarks of (height with the refit lens - height with the given lens)
    shift_se_m: float  # its jackknife standard error
    flying_height_m: float  # the map's (`MapQuality.flying_height_m`)
    displacement_px: float  # `lens_displacement_px(given, fitted)`
    rms_given_px: float  # robust residual RMS of the observations with the given lens, then the refit one
    rms_fitted_px: float
    landmarks: int  # landmarks the refit used
    seconds: float = 0.0  # CPU time of the check
    camera_kind: str = "file"  # where the camera came from (`camera_kind`): names the remedy
    judged: bool = True  # the poses were found fitting the images, so the lens was judged (`judge_lens`)

    @property
    def z(self) -> float:
        """The shift in standard errors (NaN when not measurable)."""
        if not (np.isfinite(self.shift_m) and np.isfinite(self.shift_se_m)) or self.shift_se_m <= 0:
            return float("nan")
        return abs(self.shift_m) / self.shift_se_m

    @property
    def relative_shift(self) -> float:
        """|shift| as a fraction of the flying height (NaN without one)."""
        h = self.flying_height_m
        return abs(self.shift_m) / h if np.isfinite(h) and h > 0 else float("nan")

    def consequence(self) -> str:
        """What the given lens does to the map, in user terms, short (the refusal must keep its remedy within
        `plugin.errors.MAX_PROBLEM_CHARS`: rev40 saw it cut; the other figures are in run.json's lens_check)."""
        where = "lower" if self.shift_m > 0 else "higher"
        return (f"the lens in {self.camera_file} puts the map {abs(self.shift_m):.1f} m {where} "
                f"({self.relative_shift:.0%} of the height) than the lens the images fit")

    def line(self) -> str:
        """The lens's part of the map's one-line summary."""
        return (f"lens vs images: a refit lens moves heights {self.shift_m:+.1f} +- {self.shift_se_m:.1f} m "
                f"({self.relative_shift:.1%} H)")

    def to_dict(self) -> dict[str, object]:
        """run.json's "lens_check"."""
        def r(x: float, nd: int = 3) -> float | None:
            return round(float(x), nd) if np.isfinite(x) else None

        return {"camera_file": self.camera_file, "given": {"model": self.given.model, "params": self.given.params},
                "fitted": {"model": self.fitted.model, "params": [round(p, 6) for p in self.fitted.params]},
                "height_shift_m": r(self.shift_m), "height_shift_se_m": r(self.shift_se_m), "z": r(self.z, 2),
                "relative_shift": r(self.relative_shift, 4), "flying_height_m": r(self.flying_height_m, 2),
                "edge_displacement_px": r(self.displacement_px, 2), "rms_given_px": r(self.rms_given_px),
                "rms_fitted_px": r(self.rms_fitted_px), "landmarks": self.landmarks, "cpu_s": r(self.seconds),
                "camera_kind": self.camera_kind, "judged": self.judged}


# what would give the right lens, by where the camera came from (`camera_kind`): a refusal that blamed "the camera
# file" of a map whose camera came from EXIF, where `map` takes no --camera, had no way out (rev40 defect 2)
REMEDIES = {
    "file": "fix its distortion (signs flipped, or left out: PINHOLE for a lens that bends)",
    "EXIF": "no distortion in EXIF: poses-from-exif writes cameras.txt: add the lens's there, map with "
            "--poses/--camera",
    "model": "fix the distortion of the model's camera",
}
SWITCH = "a right lens: --set quality.lens_check=false"


def camera_kind(camera_source: str, poses_source: str) -> str:
    """Where a map's camera came from, for the remedy (`REMEDIES`): "EXIF" (`poses-from-exif`'s "EXIF of ..."
    source), "model" (the camera of the COLMAP / OpenSfM model that gave the poses) or "file" (a cameras file)."""
    if camera_source.startswith("EXIF of"):
        return "EXIF"
    if camera_source and camera_source == poses_source:
        return "model"
    return "file"


@dataclass(frozen=True)
class LensNotChecked:
    """A lens check that failed (an error inside the refit): the map is kept, the failure said and recorded."""

    camera_file: str
    reason: str

    def line(self) -> str:
        """The map summary's part."""
        return f"lens not checked: {self.reason}"

    def to_dict(self) -> dict[str, object]:
        """run.json's "lens_check"."""
        return {"camera_file": self.camera_file, "error": self.reason}


def judge_lens(check: LensCheck | None, margin: float, warn_shift: float, max_shift: float, kind: str = "file",
               poses_fit: bool = True) -> tuple[list[str], list[str]]:
    """(warnings, refusals) of a lens check: a lens is called wrong only when the refit's height shift is beyond
    `margin` standard errors (the images prove another lens) and beyond `warn_shift` of the flying height (a
    warning) or `max_shift` (a refusal: the map's heights are wrong by that much). `kind`: where the camera came
    from (`camera_kind`), naming the remedy.

    The refit absorbs pose errors too: on unrefined EXIF tag poses it invented a barrel lens (k1 -0.27..-0.38) for
    a correct pinhole camera and moved heights 6.4-7.7 % of H, and z reached 5.7-10.3 on correct lenses (the
    jackknife cannot see a pull all landmarks share; rev40). So the lens is judged only when the map's pose check
    found the poses fitting the images (`poses_fit`); otherwise a shift beyond `warn_shift` is at most a warning
    naming both causes, never a refusal."""
    if check is None or not np.isfinite(check.z) or check.z <= margin or not np.isfinite(check.relative_shift):
        return [], []
    if check.relative_shift <= warn_shift:
        return [], []
    remedy = REMEDIES.get(kind, REMEDIES["file"])
    if not poses_fit:
        return [f"the images fit another lens or other poses: {check.consequence()} (the pose check did not find "
                f"the poses fitting the images, so the lens is not judged): better poses, or {remedy}"], []
    if check.relative_shift > max_shift:
        return [], [f"{check.consequence()} (limit {max_shift:.0%}): {remedy}; {SWITCH}"]
    return [f"{check.consequence()}: {remedy}; {SWITCH}"], []
