"""`sosmatch synth`: render one synthetic survey session with exact ground truth."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "synth"
HELP = "render a synthetic multi-season drone survey session (images, labels, poses, objects, footprints)"


def _pair(text: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected two comma-separated numbers, got {text!r}") from None
    return (a, b)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..synth.config import SynthConfig  # light module: dataclass defaults only

    d = SynthConfig()
    parser.add_argument("--out", type=Path, required=True, help="session directory to write")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace a session that `sosmatch synth` rendered there with other settings")
    g = parser.add_argument_group("world (equal settings give the same world)")
    g.add_argument("--world-seed", type=int, default=d.world_seed)
    g.add_argument("--world-size", type=float, default=d.world_size_m, help="side of the square world, m")
    g.add_argument("--world-resolution", type=float, default=d.world_resolution_m, help="raster cell, m")
    g = parser.add_argument_group("session")
    g.add_argument("--session-seed", type=int, default=d.session_seed,
                   help="appearance noise, objects changed, flight jitter, EKF noise")
    g.add_argument("--season", choices=["summer", "autumn", "winter", "spring"], default=d.season)
    g.add_argument("--sun-azimuth", type=float, default=None, help="deg clockwise from north (season default)")
    g.add_argument("--sun-elevation", type=float, default=None, help="deg above horizon (season default)")
    g.add_argument("--changed", type=float, default=d.changed_fraction,
                   help="fraction of objects removed in this session, at most 0.5 (as many added, up to the "
                        "world's extras: 10 %% of the objects)")
    g = parser.add_argument_group("flight")
    g.add_argument("--flight", choices=["lawnmower", "freeform"], default=d.flight)
    g.add_argument("--frames", type=int, default=d.frames)
    g.add_argument("--spacing", type=float, default=d.spacing_m, help="metres flown between images")
    g.add_argument("--altitude", type=float, default=d.altitude_m, help="metres above the mean terrain")
    g.add_argument("--line-length", type=float, default=d.line_length_m, help="lawnmower line length, m")
    g.add_argument("--line-spacing", type=float, default=d.line_spacing_m, help="lawnmower line spacing, m")
    g.add_argument("--flight-seed", type=int, default=d.flight_seed, help="shape of the free-form path")
    g.add_argument("--shift", type=_pair, default=d.shift_m, metavar="DX,DY", help="shift the path, m")
    g.add_argument("--reverse", action="store_true", help="fly the path backwards")
    g.add_argument("--rotate", type=float, default=d.rotate_deg, help="rotate the path (deg, counter-clockwise)")
    g.add_argument("--attitude-jitter", type=float, default=d.attitude_jitter_deg, help="roll/pitch std, deg")
    g.add_argument("--camera-tilt", type=float, default=d.camera_tilt_deg, metavar="DEG",
                   help="gimbal tilted forward from nadir, deg (an oblique survey: 30 = a -60 deg gimbal pitch)")
    g = parser.add_argument_group("camera")
    g.add_argument("--width", type=int, default=d.width)
    g.add_argument("--height", type=int, default=d.height)
    g.add_argument("--hfov", type=float, default=d.hfov_deg, help="horizontal field of view, deg")
    g.add_argument("--k1", type=float, default=d.lens_k1,
                   help="radial distortion k1 (COLMAP/OpenCV; negative = barrel; cameras.txt becomes SIMPLE_RADIAL)")
    g.add_argument("--k2", type=float, default=d.lens_k2, help="radial distortion k2 (with k2/p1/p2: OPENCV)")
    g.add_argument("--p1", type=float, default=d.lens_p1, help="tangential distortion p1")
    g.add_argument("--p2", type=float, default=d.lens_p2, help="tangential distortion p2")
    g.add_argument("--crop", default=d.crop_aspect, metavar="W:H",
                   help="record only the central full-width W:H band of the width x height sensor (e.g. 16:9)")
    g.add_argument("--exposure", type=float, default=None, help="exposure offset in EV (default: random)")
    g.add_argument("--noise", type=float, default=d.noise_sigma, help="read noise, 8-bit levels")
    g.add_argument("--blur", type=float, default=d.blur_sigma_px, help="optical blur sigma, px")
    g.add_argument("--jpeg-quality", type=int, default=d.jpeg_quality)
    g = parser.add_argument_group("EKF pose noise (poses_ekf.csv)")
    g.add_argument("--ekf-position-sigma", type=float, default=d.ekf_position_sigma_m, help="m")
    g.add_argument("--ekf-attitude-sigma", type=float, default=d.ekf_attitude_sigma_deg, help="deg")
    g.add_argument("--ekf-drift", type=float, default=d.ekf_drift_m_per_sqrt_m, help="m per sqrt(m) flown")
    g.add_argument("--ekf-attitude-drift", type=float, default=d.ekf_attitude_drift_deg_per_sqrt_m,
                   help="deg per sqrt(m) flown")
    g = parser.add_argument_group("geotags in the JPEGs (EXIF GPS, DJI XMP; see tools/synth/geotags.py)")
    g.add_argument("--geotags", choices=["exif", "dji"], default=None,
                   help="exif: GPS + camera EXIF; dji: also gimbal/flight angles and RelativeAltitude in XMP")
    g.add_argument("--geo-origin", type=_pair, default=d.geotag_origin_latlon, metavar="LAT,LON",
                   help="latitude, longitude of the world centre")
    g.add_argument("--gps-sigma", type=float, default=d.geotag_gps_sigma_m, help="horizontal GPS noise, m")
    g.add_argument("--gps-altitude-sigma", type=float, default=d.geotag_altitude_sigma_m, help="m")
    g.add_argument("--gps-altitude-drift", type=float, default=d.geotag_altitude_drift_m,
                   help="GPS altitude error reached at the last image (grows linearly), m")
    g.add_argument("--attitude-tag-sigma", type=float, default=d.geotag_attitude_sigma_deg,
                   help="gimbal tilt error, deg")
    g.add_argument("--yaw-tag-sigma", type=float, default=d.geotag_yaw_sigma_deg, help="compass error, deg")
    g.add_argument("--yaw-fault-lines", type=_ints, default=(), metavar="I,J",
                   help="flight lines whose XMP yaws are off by 180 degrees: 0 = the first line flown, the "
                        "crossings between lines not counted (session.json geo.flight_lines; `sosmatch poses` "
                        "numbers its flight lines the same way)")


def _ints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated line numbers, got {text!r}") from None


def config_from_args(args: argparse.Namespace):  # noqa: ANN201 (SynthConfig, imported lazily)
    """The SynthConfig of parsed arguments."""
    from ..synth.config import SynthConfig

    return SynthConfig(
        world_seed=args.world_seed, world_size_m=args.world_size, world_resolution_m=args.world_resolution,
        session_seed=args.session_seed, season=args.season, sun_azimuth_deg=args.sun_azimuth,
        sun_elevation_deg=args.sun_elevation, changed_fraction=args.changed, flight=args.flight,
        frames=args.frames, spacing_m=args.spacing, altitude_m=args.altitude, line_length_m=args.line_length,
        line_spacing_m=args.line_spacing, flight_seed=args.flight_seed, shift_m=tuple(args.shift),
        reverse=args.reverse, rotate_deg=args.rotate, attitude_jitter_deg=args.attitude_jitter,
        camera_tilt_deg=args.camera_tilt,
        width=args.width, height=args.height, hfov_deg=args.hfov, lens_k1=args.k1, lens_k2=args.k2,
        lens_p1=args.p1, lens_p2=args.p2, crop_aspect=args.crop, exposure_ev=args.exposure,
        noise_sigma=args.noise, blur_sigma_px=args.blur, jpeg_quality=args.jpeg_quality,
        ekf_position_sigma_m=args.ekf_position_sigma, ekf_attitude_sigma_deg=args.ekf_attitude_sigma,
        ekf_drift_m_per_sqrt_m=args.ekf_drift, ekf_attitude_drift_deg_per_sqrt_m=args.ekf_attitude_drift,
        geotags=args.geotags or "", geotag_origin_latlon=tuple(args.geo_origin), geotag_gps_sigma_m=args.gps_sigma,
        geotag_altitude_sigma_m=args.gps_altitude_sigma, geotag_altitude_drift_m=args.gps_altitude_drift,
        geotag_attitude_sigma_deg=args.attitude_tag_sigma, geotag_yaw_sigma_deg=args.yaw_tag_sigma,
        geotag_yaw_fault_lines=tuple(args.yaw_fault_lines),
    )


def run(args: argparse.Namespace) -> int:
    from ...workflows.synth import run as run_synth

    summary = run_synth(args.out, config_from_args(args), progress=not args.quiet, overwrite=args.overwrite)
    print(f"{summary['out']}: {summary['frames']} frames, {summary['objects_present']} objects present, "
          f"{summary['seconds_total']:.1f} s")
    return 0
