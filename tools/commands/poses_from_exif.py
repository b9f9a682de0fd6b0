"""`sosmatch poses-from-exif IMAGES --out poses.csv`: poses (UTM) and intrinsics from EXIF GPS and XMP attitude."""

from __future__ import annotations

import argparse
from pathlib import Path

from ...database.json_text import json_text
from ._common import output_file

NAME = "poses-from-exif"
HELP = "derive poses.csv (UTM, EPSG recorded) and cameras.txt from the images' EXIF GPS and XMP attitude tags"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("images", type=Path, help="image directory (or one image)")
    parser.add_argument("--out", type=output_file, required=True, help="pose CSV to write; cameras.txt goes beside it")
    parser.add_argument("--cameras", type=output_file, help="where to write cameras.txt (default: beside --out)")
    parser.add_argument("--telemetry", type=Path,
                        help="CSV with FileName,Heading,PitchAngle,RollAngle[,GPSLatitude,...] for images "
                             "whose XMP lacks attitude (e.g. Seneca's telemetry.csv)")
    parser.add_argument("--mount", default=None,
                        help="body-to-camera mounting of a fixed camera: top_forward (default), right_forward, "
                             "top_backward, left_forward")
    parser.add_argument("--pitch-sign", type=float, default=None, choices=[-1.0, 1.0],
                        help="sign of a fixed camera's airframe pitch tag (default 1: nose up positive; -1 flips it)")
    parser.add_argument("--roll-sign", type=float, default=None, choices=[-1.0, 1.0],
                        help="sign of a fixed camera's airframe roll tag (default 1: right wing down positive)")
    parser.add_argument("--sensor-width-mm", type=float,
                        help="the sensor's width, mm: its long side, whichever way the files are turned (when EXIF "
                             "has no focal-plane resolution)")
    parser.add_argument("--epsg", type=int, help="projected CRS for the poses (default: the UTM zone of the "
                        "flight's median GPS fix)")
    parser.add_argument("--refine", action="store_true",
                        help="refine the poses with ORB tie points between overlapping images, the EXIF poses "
                             "acting as priors (for consumer GPS / autopilot attitude; on by itself when images have "
                             "no attitude tags: their orientations come from the tie points)")
    parser.add_argument("--position-sigma", type=float, default=3.0, help="--refine: GPS sigma, metres (default 3)")
    parser.add_argument("--attitude-sigma", type=float, default=5.0,
                        help="--refine: attitude sigma of the tags, degrees (default 5; either method): a block the "
                             "refinement tilts beyond 3 sigma is refused, cameras it turns beyond 3 sigma are "
                             "named; with --refine-method scipy also the sigma of the attitude priors")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace pose/camera files this command wrote before from other images or options")
    parser.add_argument("--refine-method", choices=["colmap", "scipy"], default="colmap",
                        help="--refine: colmap = COLMAP's pose-prior bundle adjustment (GPS position priors, "
                             "seconds; default), scipy = position and attitude priors (minutes)")


def run(args: argparse.Namespace) -> int:
    from ...workflows import poses_from_exif as wf

    result = wf.run(
        args.images, args.out, telemetry=args.telemetry,
        mount=args.mount or wf.DEFAULT_MOUNT,
        pitch_sign=args.pitch_sign if args.pitch_sign is not None else wf.DEFAULT_PITCH_SIGN,
        roll_sign=args.roll_sign if args.roll_sign is not None else wf.DEFAULT_ROLL_SIGN,
        sensor_width_mm=args.sensor_width_mm, epsg=args.epsg, cameras_out=args.cameras,
        refine=args.refine, position_sigma_m=args.position_sigma, attitude_sigma_deg=args.attitude_sigma,
        refine_method=args.refine_method, overwrite=args.overwrite,
    )
    print(json_text(result.summary, indent=2))
    return 0
