"""`sosmatch synth-from-ortho GEOTIFF --out SESSION`: nadir views with exact poses from an orthophoto."""

from __future__ import annotations

import argparse
from pathlib import Path

from ...database.json_text import json_text

NAME = "synth-from-ortho"
HELP = "render a session (images, exact poses, footprints) of nadir views from a georeferenced orthophoto"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("geotiff", type=Path, help="north-up orthophoto in a projected CRS (GeoTIFF)")
    parser.add_argument("--out", type=Path, required=True, help="session directory to write")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace a session this command rendered there with other settings")
    parser.add_argument("--path", default="lawnmower", choices=["lawnmower", "line", "cross"])
    height = parser.add_mutually_exclusive_group()  # each sets the other (GSD = altitude / focal length in px)
    height.add_argument("--altitude", type=float, help="metres above the ground (default: from --gsd)")
    height.add_argument("--gsd", type=float, help="ground sampling distance in m/px, sets the altitude (default 2.5; "
                        "not with --altitude)")
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--hfov", type=float, default=60.0, help="horizontal field of view, degrees")
    parser.add_argument("--frame-spacing", type=float, help="metres between frames (default: footprint / 8)")
    parser.add_argument("--line-spacing", type=float, help="metres between lines (default: footprint width / 2)")
    parser.add_argument("--heading", type=float, help="line direction, degrees from grid north (default: long side)")
    parser.add_argument("--offset", type=float, default=0.0, help="shift the lines sideways by this many metres")
    parser.add_argument("--frames", type=int, help="at most this many frames (the first along the path)")
    parser.add_argument("--max-tilt", type=float, default=0.0, help="random tilt of each view, degrees (exact)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--ekf-position-sigma", type=float, default=0.0, help="noise of poses_ekf.csv, metres")
    parser.add_argument("--ekf-attitude-sigma", type=float, default=0.0, help="noise of poses_ekf.csv, degrees")


def run(args: argparse.Namespace) -> int:
    from ...workflows.synth_from_ortho import run as render

    summary = render(args.geotiff, args.out, path=args.path, altitude_m=args.altitude, gsd_m=args.gsd,
                     width=args.width, height=args.height, hfov_deg=args.hfov, frame_spacing_m=args.frame_spacing,
                     line_spacing_m=args.line_spacing, heading_deg=args.heading, offset_m=args.offset,
                     frames=args.frames, max_tilt_deg=args.max_tilt, seed=args.seed,
                     ekf_position_sigma_m=args.ekf_position_sigma, ekf_attitude_sigma_deg=args.ekf_attitude_sigma,
                     overwrite=args.overwrite)
    print(json_text(summary, indent=2))
    return 0
