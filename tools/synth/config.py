"""All settings of one synthetic session, with the defaults and the reasons for them.

Defaults (100 m above ground, 640x480, 65 deg horizontal field of view):
- focal length 502 px -> ground sampling distance ~0.20 m; one image covers ~127 m x 95 m.
- a frame every 7 m along track: consecutive frames overlap by 93 %, a point on the ground stays in view for
  ~13 consecutive frames of one pass (mapping keeps a keyframe every 2 m of travel, so every frame is one).
- lawnmower lines 160 m long, 30 m apart: 76 % side overlap, so an object is seen from 2-4 passes and in
  >= 6 frames (typically 15-40); 100 frames fly ~4 lines and cover ~220 m x 250 m.
- the world is 600 m x 600 m so shifted, rotated or free-form flights still stay inside it.
- EKF noise: 0.3 m / 0.3 deg white noise and a random-walk drift of 0.05 m per sqrt(m) flown (~1.3 m after
  700 m), a consumer drone's GNSS/INS class.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ...plugin.errors import InputError

if TYPE_CHECKING:  # the heavy modules (cv2) are imported when used, so that `sosmatch --help` stays fast
    from ...plugin.geometry import Camera
    from .flights import EkfNoise, FlightConfig
    from .geotags import GeotagSettings
    from .world import WorldConfig

SEASON_NAMES = ("summer", "autumn", "winter", "spring")
FLIGHT_KINDS = ("lawnmower", "freeform")
# Change detection needs pairs with many changed objects to measure its precision and recall with some
# confidence (BENCHMARKS.md, Change detection); half of the objects gone is already a different landscape.
MAX_CHANGED_FRACTION = 0.5
MAX_CAMERA_TILT_DEG = 45.0  # an oblique survey gimbal (-45 deg pitch); beyond, a 65 deg frame reaches the horizon


@dataclass(frozen=True)
class SynthConfig:
    # world (sessions with equal world settings share the world exactly)
    world_seed: int = 0
    world_size_m: float = 600.0
    world_resolution_m: float = 0.15
    # session
    session_seed: int = 0
    season: str = "summer"
    sun_azimuth_deg: float | None = None  # None: the season's default (clockwise from north)
    sun_elevation_deg: float | None = None
    # share of objects removed in this session; as many extras are added, up to the world's pool of extras (10 %
    # of the objects, `world.EXTRA_FRACTION`): beyond that only removals grow (e.g. 0.3: 30 % removed, 10 % added)
    changed_fraction: float = 0.04
    # flight
    flight: str = "lawnmower"
    frames: int = 100
    spacing_m: float = 7.0
    altitude_m: float = 100.0
    line_length_m: float = 160.0
    line_spacing_m: float = 30.0
    flight_seed: int = 0
    shift_m: tuple[float, float] = (0.0, 0.0)
    reverse: bool = False
    rotate_deg: float = 0.0
    attitude_jitter_deg: float = 1.5
    camera_tilt_deg: float = 0.0  # forward from nadir, along the direction of travel (`flights.FlightConfig`)
    # camera
    width: int = 640
    height: int = 480  # of the sensor; `crop_aspect` may keep only a central band of it
    hfov_deg: float = 65.0  # of the ideal (pinhole) part of the lens; barrel distortion widens the real view
    # lens distortion in COLMAP's OPENCV terms (normalised coordinates, the same at every resolution): all zero is
    # a PINHOLE camera, only k1 a SIMPLE_RADIAL one, anything else OPENCV; the images are rendered through it
    lens_k1: float = 0.0
    lens_k2: float = 0.0
    lens_p1: float = 0.0
    lens_p2: float = 0.0
    # "W:H" (e.g. "16:9"): the images are the central full-width W:H band of the sensor, as consumer drones
    # record video-format stills; the principal point moves with the crop, the focal length does not
    crop_aspect: str = ""
    exposure_ev: float | None = None  # None: season bias + a random session offset
    noise_sigma: float = 1.5  # read noise, 8-bit digital numbers
    blur_sigma_px: float = 0.6
    jpeg_quality: int = 88
    # EKF pose noise
    ekf_position_sigma_m: float = 0.3
    ekf_attitude_sigma_deg: float = 0.3
    ekf_drift_m_per_sqrt_m: float = 0.05
    ekf_attitude_drift_deg_per_sqrt_m: float = 0.01
    # geotags in the JPEGs (tools/synth/geotags.py): "" none, "exif" = EXIF GPS + camera tags (a compact camera),
    # "dji" = also DJI XMP (gimbal and flight angles, RelativeAltitude); with a consumer drone's errors
    geotags: str = ""
    geotag_origin_latlon: tuple[float, float] = (47.0, 8.0)  # where the world centre lies
    geotag_gps_sigma_m: float = 1.0  # horizontal, per axis
    geotag_altitude_sigma_m: float = 1.5
    geotag_altitude_drift_m: float = 0.0  # GPS altitude error growing linearly to this at the last image
    geotag_attitude_sigma_deg: float = 0.5  # gimbal tilt error
    geotag_yaw_sigma_deg: float = 1.0  # compass error
    geotag_yaw_fault_lines: tuple[int, ...] = ()  # flight lines whose XMP yaws are 180 degrees off

    def world_config(self) -> WorldConfig:
        from .world import WorldConfig

        return WorldConfig(seed=self.world_seed, size_m=self.world_size_m, resolution_m=self.world_resolution_m)

    def flight_config(self) -> FlightConfig:
        from .flights import FlightConfig

        return FlightConfig(kind=self.flight, frames=self.frames, spacing_m=self.spacing_m,
                            altitude_m=self.altitude_m, line_length_m=self.line_length_m,
                            line_spacing_m=self.line_spacing_m, seed=self.flight_seed,
                            shift_m=tuple(self.shift_m), reverse=self.reverse, rotate_deg=self.rotate_deg,
                            attitude_jitter_deg=self.attitude_jitter_deg, camera_tilt_deg=self.camera_tilt_deg)

    def ekf_noise(self) -> EkfNoise:
        from .flights import EkfNoise

        return EkfNoise(self.ekf_position_sigma_m, self.ekf_attitude_sigma_deg, self.ekf_drift_m_per_sqrt_m,
                        self.ekf_attitude_drift_deg_per_sqrt_m)

    def geotag_settings(self) -> GeotagSettings:
        from .geotags import GeotagSettings

        return GeotagSettings(kind=self.geotags, origin_latlon=tuple(self.geotag_origin_latlon),
                              gps_sigma_m=self.geotag_gps_sigma_m, gps_altitude_sigma_m=self.geotag_altitude_sigma_m,
                              gps_altitude_drift_m=self.geotag_altitude_drift_m,
                              attitude_tag_sigma_deg=self.geotag_attitude_sigma_deg,
                              yaw_tag_sigma_deg=self.geotag_yaw_sigma_deg,
                              yaw_fault_lines=tuple(int(v) for v in self.geotag_yaw_fault_lines))

    def sensor_camera(self) -> Camera:
        """The camera of the whole sensor (`width` x `height`), lens included."""
        from ...plugin.geometry import Camera

        f = (self.width / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)
        k1, k2, p1, p2 = self.lens_k1, self.lens_k2, self.lens_p1, self.lens_p2
        if k2 == p1 == p2 == 0.0:
            model, extra = ("PINHOLE", ()) if k1 == 0.0 else ("SIMPLE_RADIAL", (k1,))
        else:
            model, extra = "OPENCV", (k1, k2, p1, p2)
        return Camera(self.width, self.height, f, f, self.width / 2.0, self.height / 2.0, model, extra)

    def crop_height(self) -> int:
        """Rows of the recorded images: the sensor height, or the full-width `crop_aspect` band of it."""
        if not self.crop_aspect:
            return self.height
        a, b = _aspect(self.crop_aspect)
        return int(round(self.width * b / a))

    def camera(self) -> Camera:
        """The camera of the recorded images (the sensor camera, cropped to `crop_aspect` if set)."""
        sensor = self.sensor_camera()
        rows = self.crop_height()
        if rows == self.height:
            return sensor
        return sensor.cropped(0, (self.height - rows) / 2.0, self.width, rows)

    def sun(self) -> tuple[float, float]:
        from .appearance import SEASON_LOOKS

        look = SEASON_LOOKS[self.season]
        az = look.sun_azimuth_deg if self.sun_azimuth_deg is None else self.sun_azimuth_deg
        el = look.sun_elevation_deg if self.sun_elevation_deg is None else self.sun_elevation_deg
        return float(az) % 360.0, float(el)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["shift_m"] = list(self.shift_m)
        d["geotag_origin_latlon"] = list(self.geotag_origin_latlon)
        d["geotag_yaw_fault_lines"] = list(self.geotag_yaw_fault_lines)
        return d

    def validate(self) -> None:
        """Raise InputError for values that cannot make a session."""
        def bad(msg: str) -> None:
            raise InputError(msg)

        # every type first: SynthConfig(width=320.5) passed and failed in the renderer's slicing, width="320" in
        # the range tests below (tracebacks from Python callers; the CLI parses types itself)
        for f in dataclasses.fields(self):
            problem = _type_problem(str(f.type), getattr(self, f.name))
            if problem:
                bad(f"{f.name} must be {problem}, got {getattr(self, f.name)!r}")
        # every number then: a NaN passes each "< 0" and "between" test below and failed deep in the renderer
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if any(isinstance(v, float) and not math.isfinite(v)
                   for v in (value if isinstance(value, (tuple, list)) else (value,))):
                bad(f"{f.name} must be a finite number, got {value!r}")
        if self.season not in SEASON_NAMES:
            bad(f"season must be one of {', '.join(SEASON_NAMES)}, got {self.season!r}")
        if self.flight not in FLIGHT_KINDS:
            bad(f"flight must be one of {', '.join(FLIGHT_KINDS)}, got {self.flight!r}")
        for name in ("world_seed", "session_seed", "flight_seed"):
            if getattr(self, name) < 0:
                bad(f"{name} must be >= 0")
        if not 1 <= self.frames <= 100_000:
            bad("frames must be between 1 and 100000")
        if not 16 <= self.width <= 8192 or not 16 <= self.height <= 8192:
            bad("image width and height must be between 16 and 8192 pixels")
        if not 10.0 <= self.hfov_deg <= 120.0:
            bad("hfov_deg (--hfov) must be between 10 and 120 degrees")
        if self.crop_aspect:
            try:
                _aspect(self.crop_aspect)
            except ValueError as exc:
                bad(str(exc))
            if not 16 <= self.crop_height() < self.height:
                bad(f"crop_aspect (--crop) {self.crop_aspect} must keep a band narrower than the "
                    f"{self.width}x{self.height} sensor (a W:H wider than the sensor's) and at least 16 rows")
        if max(abs(self.lens_k1), abs(self.lens_k2)) > 1.0 or max(abs(self.lens_p1), abs(self.lens_p2)) > 0.05:
            bad("lens distortion out of range (|k1|, |k2| <= 1, |p1|, |p2| <= 0.05)")
        if self.sensor_camera().lens_folds():
            bad("the lens distortion folds the image over (rays are not one-to-one with pixels inside the sensor): "
                "use a smaller |k1| / |k2| or a narrower --hfov")
        if not self.spacing_m > 0 or not self.line_length_m > 0 or not self.line_spacing_m > 0:
            bad("spacing_m, line_length_m and line_spacing_m (--spacing, --line-length, --line-spacing) must be "
                "positive")
        if not 40.0 <= self.altitude_m <= 1000.0:
            bad("altitude_m (--altitude) must be between 40 and 1000 m (objects are up to 25 m tall)")
        if not 50.0 <= self.world_size_m <= 3000.0:
            bad("world_size_m (--world-size) must be between 50 and 3000 m")
        if not 0.05 <= self.world_resolution_m <= 1.0:
            bad("world_resolution_m (--world-resolution) must be between 0.05 and 1.0 m")
        if self.world_size_m / self.world_resolution_m > 30000:
            bad("world_size_m / world_resolution_m (--world-size / --world-resolution) must stay below 30000 cells")
        if not 0.0 <= self.changed_fraction <= MAX_CHANGED_FRACTION:
            bad(f"changed_fraction (--changed) must be between 0 and {MAX_CHANGED_FRACTION}")
        el = self.sun()[1]
        if not 5.0 <= el <= 90.0:
            bad("sun elevation must be between 5 and 90 degrees")
        if not 1 <= self.jpeg_quality <= 100:
            bad("jpeg_quality (--jpeg-quality) must be between 1 and 100")
        if self.noise_sigma < 0 or self.blur_sigma_px < 0 or self.attitude_jitter_deg < 0:
            bad("noise, blur and jitter must be >= 0")
        if self.attitude_jitter_deg > 10:
            bad("attitude_jitter_deg (--attitude-jitter) must be <= 10 (the camera is nadir)")
        if not 0.0 <= self.camera_tilt_deg <= MAX_CAMERA_TILT_DEG:
            bad(f"camera_tilt_deg (--camera-tilt) must be between 0 and {MAX_CAMERA_TILT_DEG:g} (an oblique survey; "
                "beyond, the top of a wide frame sees the horizon)")
        if min(self.ekf_position_sigma_m, self.ekf_attitude_sigma_deg, self.ekf_drift_m_per_sqrt_m,
               self.ekf_attitude_drift_deg_per_sqrt_m) < 0:
            bad("EKF noise settings must be >= 0")
        if self.exposure_ev is not None and abs(self.exposure_ev) > 4:
            bad("exposure_ev (--exposure) must be within +-4")
        from .geotags import GEOTAG_KINDS

        if self.geotags not in GEOTAG_KINDS:
            bad(f"geotags must be one of exif, dji (or empty for none), got {self.geotags!r}")
        lat, lon = self.geotag_origin_latlon
        # beyond UTM's latitudes the tags are placed in UPS (`geodesy.utm_epsg`), as `map` reads them
        if not (abs(lat) <= 90 and abs(lon) <= 180):
            bad("geotag origin must be a latitude within +-90 and a longitude within +-180 degrees")
        if min(self.geotag_gps_sigma_m, self.geotag_altitude_sigma_m, self.geotag_attitude_sigma_deg,
               self.geotag_yaw_sigma_deg) < 0 or not math.isfinite(self.geotag_altitude_drift_m):
            bad("geotag noise settings must be >= 0 (the drift may have either sign)")
        if self.geotag_yaw_fault_lines and (self.geotags != "dji" or self.flight != "lawnmower"):
            bad("a yaw fault on flight lines needs geotags=dji and a lawnmower flight")


def _number(v: object, integer: bool = False) -> bool:
    if isinstance(v, bool):
        return False
    return isinstance(v, int) if integer else isinstance(v, (int, float))


def _type_problem(annotation: str, value: object) -> str:
    """What `value` should be for a field annotated `annotation` ("" when it is)."""
    if annotation.endswith("| None"):
        if value is None:
            return ""
        annotation = annotation[: -len("| None")].strip()
    if annotation == "int":
        return "" if _number(value, integer=True) else "an integer"
    if annotation == "float":
        return "" if _number(value) else "a number"
    if annotation == "bool":
        return "" if isinstance(value, bool) else "true or false"
    if annotation == "str":
        return "" if isinstance(value, str) else "text"
    if annotation.startswith("tuple["):
        integer = annotation.startswith("tuple[int")
        ok = isinstance(value, (tuple, list)) and all(_number(v, integer) for v in value)
        return "" if ok else f"a list of {'integers' if integer else 'numbers'}"
    return ""


def _aspect(text: str) -> tuple[float, float]:
    """("16:9") -> (16.0, 9.0); ValueError on anything else."""
    try:
        a, b = (float(v) for v in text.split(":"))
    except ValueError:
        raise ValueError(f"crop_aspect must be W:H such as 16:9, got {text!r}") from None
    if not (a > 0 and b > 0 and math.isfinite(a) and math.isfinite(b)):
        raise ValueError(f"crop_aspect must be W:H with positive numbers, got {text!r}")
    return a, b
