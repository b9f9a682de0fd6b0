"""`sosmatch map`: images + fixed poses -> a mapped session directory (SOS-Match section 1).

Stages (docs/ARCHITECTURE.md, "The data walk"):
1. inputs: poses from a pose CSV (quaternion or yaw/pitch/roll), a COLMAP model, an OpenSfM reconstruction or a
   `sosmatch synth` session (Earth-centred ones converted to their UTM zone); intrinsics from a cameras file, the
   COLMAP model or the synth session; images matched to poses by name; then the poses checked against the images
   (their matches, their GPS: `workflows.pose_check`);
2. keyframes every `keyframes.interval_m` of travel;
3. per keyframe (cached): segmentation, mask description, image-motion statistics to the previous keyframe;
4. tracking (the method spec 1.5);
5. COLMAP database: mask centroids as keypoints, every pair of observations of a long-enough track as a
   verified match (checked against the known poses with the Sampson distance);
6. pycolmap triangulation with the fixed poses, points-only BA, landmark filters, metric sizes
   (`sosmatch.workflows.triangulation`);
7. outputs: database.db, sparse/, landmarks.sosmap, landmarks.ply, landmarks.csv, run.json.

Robustness: SESSION_DIR is taken through `sosmatch.database.outputs` (refusals, lock, marker). Everything is
built in SESSION_DIR/.partial and moved into place at the end (run.json last, so a directory with run.json is
complete). The per-keyframe results live in SESSION_DIR/.partial/cache/, each written atomically and valid
while its image (and the previous keyframe's) is unchanged, so a killed or failed run resumes where it stopped
and ends with the same outputs. A complete session made from other inputs or parameters is replaced only with
`overwrite=True`.
"""

from ...plugin.errors import InputError
from .inputs import (
    IMAGE_EXTENSIONS,
    MapInputs,
    in_flight_order,
    input_fingerprints,
    load_inputs,
    pose_file_beside,
    refuse_text_model_names,
    warn_of_pose_file_beside,
)
from .keyframes import cached_descriptors, describe_keyframes
from .output_dir import OUTPUTS, PARTIAL
from .workflow import MapSummary, map_origin, run

__all__ = [
    "IMAGE_EXTENSIONS", "OUTPUTS", "PARTIAL", "InputError", "MapInputs", "MapSummary", "cached_descriptors",
    "describe_keyframes", "in_flight_order", "input_fingerprints", "load_inputs", "map_origin",
    "pose_file_beside", "refuse_text_model_names", "run", "warn_of_pose_file_beside",
]
