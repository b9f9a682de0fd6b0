"""`sosmatch poses IMAGES --out DIR`: camera poses and intrinsics from the images themselves, by COLMAP's
structure from motion, georegistered on the images' GPS; the default source of poses for a folder of photos.

    from sosmatch.workflows import poses
    result = poses.run("flight/images", "flight/poses")         # -> PosesResult
    print(result.line())

Modules: `job` (run, the resumable stages, `PosesFromImages` for `map`), `checks` (georegistration or a local
frame, the comparison with the tags, plausibility warnings), `result` (the output directory, `load_result`,
`map_inputs`), `opensfm` (OpenDroneMap / OpenSfM projects).

Stages (`run`): the images' metadata (`image_priors`: GPS, attitude tags, RelativeAltitude, cameras) ->
features -> the pairs GPS says overlap -> matching -> incremental (or global) mapping (`workflows.sfm`) ->
georegistration on GPS (`plugin.georegistration`: the vertical from the attitude tags checked against the GPS
altitudes, scale/yaw/offset robust to wrong fixes, heights that do not follow a drifting GPS altitude) ->
comparison with the tags (orientations per image, flight lines whose yaw contradicts the images) -> outputs.

Outputs in DIR (through `database.outputs`: a killed run resumes from the matched database; a directory not
written by `sosmatch poses` is never touched):
- `poses.csv`: registered images, world_from_camera, `# crs: EPSG:<utm>` (or `local`); `map` reads it,
- `cameras.txt`: the cameras as SfM refined them (focal length, distortion: SIMPLE_RADIAL by default),
- `sparse/`: the georegistered COLMAP model (cameras, images, 3D points), `database.db`: COLMAP's database,
- `poses.json` (last): what was measured: registered and unregistered images, the georegistration (GPS noise,
  outliers, vertical source, GPS altitude drift), per-image differences to the GPS and the tags, contradicting
  flight lines, warnings and timings.

Loud, never a quiet success: fewer than `sfm.min_registered_fraction` of the images registered, or fewer than
3, is an error (exit 2); unregistered images, GPS fixes far off the reconstruction, a GPS noise far above
`sfm.gps_sigma_m`, a drifting GPS altitude and contradicting tags are warnings, repeated in `poses.json` and
counted in the summary line. Without GPS the poses are in a local, levelled frame (scale from RelativeAltitude
if present, else cameras set `nominal_height_m` above the ground) with a warning.
"""

from .checks import NOMINAL_HEIGHT_M, gps_noise_warning
from .job import PosesFromImages, compute_poses, identity_of, run
from .opensfm import opensfm_poses, run_opensfm
from .result import OUTPUTS, RECORD, PosesResult, load_result, map_inputs

__all__ = [
    "NOMINAL_HEIGHT_M", "OUTPUTS", "RECORD", "PosesFromImages", "PosesResult", "compute_poses", "gps_noise_warning",
    "identity_of", "load_result", "map_inputs", "opensfm_poses", "run", "run_opensfm",
]
