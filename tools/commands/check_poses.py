"""`sosmatch check-poses`: do given poses agree with what the images show? (`workflows.pose_check`; `map` runs the
same check as its first stage.)"""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import add_params_arguments, output_file, params_from_args

NAME = "check-poses"
HELP = ("check poses against the images (pose-free image matches vs the poses' epipolar geometry: wrong headings, "
        "drifting heights, centres on a tilted plane); exit 2 when the poses contradict the images")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--images", type=Path, help="image directory (default: the synth session's images/)")
    parser.add_argument("--poses", type=Path,
                        help="pose CSV, COLMAP model or `sosmatch synth` session directory (as `sosmatch map`); "
                             "default: the images' EXIF/XMP poses (as `sosmatch poses-from-exif`)")
    parser.add_argument("--camera", type=Path, help="intrinsics: cameras.txt, cameras.bin or a COLMAP model")
    parser.add_argument("--convention", choices=["world_from_camera", "camera_from_world"],
                        help="pose convention of the CSV (overrides its '# convention:' comment)")
    parser.add_argument("--out", type=output_file, help="write the figures here (JSON, e.g. pose_check.json)")
    parser.add_argument("--warn-only", action="store_true", help="report a refusal but exit 0")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an --out file this command wrote before from other inputs or settings")
    add_params_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ...plugin.errors import InputError
    from ...workflows import map as map_workflow
    from ...workflows import pose_check
    from ...workflows.map.inputs import distinct_images

    if args.poses is None:
        if args.images is None:
            raise InputError("give --poses, or --images (poses from their EXIF/XMP tags)")
        from ...workflows.poses_from_exif import map_inputs_from_images

        inputs = map_inputs_from_images(args.images)
    else:
        inputs = map_workflow.load_inputs(args.images, args.poses, args.camera, args.convention)
    # as `map` does before anything else: a copy of an image (or a repeated view at one recorded position) is
    # left out, with the map's warning. Kept, its pair with the original has no baseline, spends the check's pair
    # budget, shifts which pairs are checked, and check-poses' figures differed from the map's own check of the
    # same inputs (BENCHMARKS.md, "check-poses and copies of images")
    said = len(inputs.warnings)
    inputs, _ = distinct_images(inputs)
    params = params_from_args(args)
    if args.out is not None:  # a user's file: never an input, never one sosmatch did not write
        result = pose_check.check_to_file(inputs.image_paths, inputs.poses, inputs.camera, params, args.out,
                                          refuse=not args.warn_only, sources=inputs.sources,
                                          overwrite=args.overwrite, epsg=inputs.epsg,
                                          input_warnings=inputs.warnings[said:])
    else:
        result = pose_check.run(inputs.image_paths, inputs.poses, inputs.camera, params, refuse=not args.warn_only,
                                sources=inputs.sources, epsg=inputs.epsg, input_warnings=inputs.warnings[said:])
    print(result.line())
    return 0
