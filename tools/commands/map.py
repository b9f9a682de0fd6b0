"""`sosmatch map`: images + fixed poses -> a mapped session (COLMAP database, sparse model, landmark map)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ...plugin.errors import InputError
from ._common import add_params_arguments, params_from_args

NAME = "map"
HELP = "build a session's landmark map from images and fixed poses (segments -> tracks -> COLMAP -> landmarks)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--images", type=Path, help="image directory (default: the synth session's images/)")
    parser.add_argument("--poses", type=Path,
                        help="pose CSV (quaternion or yaw/pitch/roll), COLMAP model (dir or images.bin/.txt), "
                             "or a `sosmatch synth` session directory (default: made from the images, see "
                             "--pose-source)")
    parser.add_argument("--pose-source", choices=["sfm", "exif"], default=None,
                        help="without --poses: sfm (default) = COLMAP structure from motion georegistered on the "
                             "GPS, as `sosmatch poses` (its outputs go to OUT/poses); exif = the EXIF/XMP poses as "
                             "they are (`poses-from-exif`; see --refine; images without attitude tags get their "
                             "orientations from tie points, as with --refine)")
    parser.add_argument("--telemetry", type=Path,
                        help="without --poses: attitude CSV for images whose XMP lacks it (see poses-from-exif)")
    parser.add_argument("--refine", action="store_true",
                        help="--pose-source exif: refine the EXIF poses from tie points first (poses-from-exif "
                             "--refine)")
    parser.add_argument("--epsg", type=int,
                        help="without --poses: the projected CRS of the poses, an EPSG code (default: the UTM zone "
                             "of the flight's median GPS fix); give flights of one site on either side of a UTM zone "
                             "edge the same one, as `match` advises")
    parser.add_argument("--camera", type=Path,
                        help="intrinsics: cameras.txt, cameras.bin or a COLMAP model (default: from --poses)")
    parser.add_argument("--out", type=Path, required=True,
                        help="session directory to write: database.db, sparse/ (COLMAP model), landmarks.sosmap/.csv/"
                        ".ply, quality.png, pose_check.json, run.json (and poses/ when poses come from structure from "
                        "motion)")
    parser.add_argument("--convention", choices=["world_from_camera", "camera_from_world"],
                        help="pose convention of the CSV (overrides its '# convention:' comment)")
    parser.add_argument("--ekf", action="store_true", help="synth session: use the noisy poses_ekf.csv")
    parser.add_argument("--strict", action="store_true",
                        help="images without a pose or poses without an image are an error, not a warning")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace a session made from other inputs or settings in --out (a folder that is not a "
                             "`sosmatch map` output is refused all the same); also compute again cached keyframes "
                             "another sosmatch version made")
    parser.add_argument("--text", action="store_true", help="write sparse/ as a COLMAP text model")
    parser.add_argument("--keep-cache", action="store_true",
                        help="keep the per-keyframe cache (OUT/.partial/cache) after a successful run")
    parser.add_argument("--workers", type=int, default=1,
                        help="processes for segmentation and description (spawn costs ~3 s; pays off on long runs)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    add_params_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ...workflows import map as map_workflow

    if args.workers < 1:  # was taken as 1 without a word (match refuses it, batch takes 0 for one per core)
        raise InputError(f"--workers must be >= 1, got {args.workers}")
    params = params_from_args(args)
    # options of the other pose source would be silently ignored: say so instead
    if args.poses is not None and (args.telemetry is not None or args.refine or args.pose_source or args.epsg):
        raise InputError("--pose-source, --telemetry, --refine and --epsg apply only without --poses (poses from the "
                         "images; a pose file keeps its own CRS)")
    if args.refine and args.pose_source != "exif":
        raise InputError("--refine refines EXIF/XMP poses: give --pose-source exif (structure from motion, the "
                         "default, needs no refinement)")
    if args.poses is None and (args.camera is not None or args.convention is not None or args.ekf):
        raise InputError("--camera, --convention and --ekf need --poses (without it, EXIF gives the camera)")
    if args.poses is None:
        if args.images is None:
            raise InputError("give --poses, or --images (poses by structure from motion or from EXIF/XMP)")
        map_workflow.warn_of_pose_file_beside(args.images)  # --poses forgotten? (structure from motion takes minutes)
        if args.text and Path(args.images).is_dir():  # before the poses are made (the map's own check: its inputs)
            from ...database.images import image_files

            map_workflow.refuse_text_model_names(image_files(args.images))
        if args.pose_source == "exif":
            from ...workflows.poses_from_exif import map_inputs_from_images

            inputs = map_inputs_from_images(args.images, args.telemetry, args.refine, epsg=args.epsg)
        else:
            from ...workflows.poses import PosesFromImages

            inputs = PosesFromImages(args.images, params, telemetry=args.telemetry, epsg=args.epsg)
    else:
        inputs = map_workflow.load_inputs(args.images, args.poses, args.camera, args.convention, args.ekf,
                                          args.strict)
    summary = map_workflow.run(params, inputs, args.out, overwrite=args.overwrite, text_model=args.text,
                               keep_cache=args.keep_cache, workers=args.workers,
                               progress=not (args.no_progress or args.quiet))
    print(summary.line())
    return 0
