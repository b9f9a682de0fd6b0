"""`sosmatch poses IMAGES --out DIR`: poses and cameras from the images by COLMAP's structure from motion."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import add_params_arguments, params_from_args

NAME = "poses"
HELP = ("camera poses and intrinsics from a folder of photos: COLMAP structure from motion georegistered on "
        "their GPS (poses.csv, cameras.txt, a COLMAP model, poses.json)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("images", type=Path, nargs="?", help="image directory")
    parser.add_argument("--opensfm", type=Path, metavar="PROJECT",
                        help="take the poses and cameras of an OpenDroneMap / OpenSfM project (its "
                             "opensfm/reconstruction.json, converted to UTM) instead of computing them; IMAGES, if "
                             "given, rescales the cameras to the image files")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--telemetry", type=Path,
                        help="CSV with FileName,Heading,PitchAngle,RollAngle[,GPSLatitude,...] for images whose "
                             "EXIF/XMP lacks them (as poses-from-exif)")
    parser.add_argument("--takeoff-altitude", type=float,
                        help="altitude of the take-off point (m, the GPS datum): heights = this + DJI "
                             "RelativeAltitude (default: from the GPS at the start of the flight)")
    parser.add_argument("--sensor-width-mm", type=float,
                        help="the sensor's width, mm: its long side, whichever way the files are turned (when EXIF "
                             "has no focal-plane resolution)")
    parser.add_argument("--nominal-height", type=float, default=100.0,
                        help="without GPS and RelativeAltitude: the flight height above ground that sets the local "
                             "frame's scale (m)")
    parser.add_argument("--epsg", type=int,
                        help="the projected CRS of the poses, an EPSG code (default: the UTM zone of the flight's "
                             "median GPS fix); flights of one site on either side of a UTM zone edge: the same one")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace a previous `poses` output of other inputs, or of the same ones made by another "
                             "sosmatch version")
    add_params_arguments(parser)
    parser.epilog = ("Flight lines (in the warnings and poses.json) are found from the camera track and numbered 0, "
                     "1, ... in the order flown; the short crossings between lines are no lines, as in `sosmatch "
                     "synth --yaw-fault-lines`.")


def run(args: argparse.Namespace) -> int:
    from ...plugin.errors import InputError
    from ...workflows import poses

    if args.opensfm is not None:
        if args.epsg is not None:  # OpenSfM's reference_lla gives the CRS; the option would be ignored in silence
            raise InputError("--epsg applies to an image directory, not to --opensfm (its poses keep their CRS)")
        print(poses.run_opensfm(args.opensfm, args.out, args.images, overwrite=args.overwrite).line())
        return 0
    if args.images is None:
        raise InputError("give an image directory (or --opensfm PROJECT)")
    result = poses.run(args.images, args.out, params_from_args(args), telemetry=args.telemetry,
                       takeoff_altitude_m=args.takeoff_altitude, sensor_width_mm=args.sensor_width_mm,
                       nominal_height_m=args.nominal_height, overwrite=args.overwrite, epsg=args.epsg)
    print(result.line())
    return 0
