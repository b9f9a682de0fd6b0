"""OpenDroneMap / OpenSfM projects as a pose source: their reconstruction in UTM (`opensfm_poses`, also read by
`map --poses PROJECT`) and as a `poses` output directory (`run_opensfm`)."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from ...database.atomic import write_text_atomic
from ...database.cameras import camera_for_image_files, format_cameras_txt
from ...database.json_text import json_default
from ...database.output_markers import fingerprint
from ...database.outputs import open_output_dir
from ...database.poses import format_poses_csv
from ...plugin.geometry import Camera, Poses
from ..image_priors import list_images
from .job import _image_identity
from .result import FILES, RECORD, PosesResult, load_result

log = logging.getLogger(__name__)

def opensfm_poses(project: str | Path, image_dir: str | Path | None = None
                  ) -> tuple[Poses, dict[str, Camera], dict[str, str], int, dict[str, Any]]:
    """Poses of an OpenSfM / OpenDroneMap reconstruction (`database.opensfm`) in the UTM grid of its
    reference_lla (a local frame without one), and its cameras in pixels of the images in `image_dir` (the
    project may have processed resized copies: same aspect, rescaled). Returns (poses, cameras by OpenSfM id,
    camera of each image, EPSG (0: local), what was done)."""
    from ...database.opensfm import read_opensfm_reconstruction
    from ...plugin.geodesy import topocentric_to_grid

    rec = read_opensfm_reconstruction(project)
    poses = rec.poses
    info: dict[str, Any] = {"source": str(rec.path), "shots": len(poses), "other_reconstructions":
                            rec.other_reconstructions}
    if rec.other_reconstructions:
        # only the largest is read: the others' images would otherwise just count as "without a pose" later
        log.warning("%d other reconstruction(s) (sizes %s) in %s ignored: only the largest (%d shots) is read",
                    len(rec.other_reconstructions), ", ".join(map(str, rec.other_reconstructions)), rec.path,
                    len(poses))
    epsg = 0
    if rec.reference_lla is not None:
        centers, grid_from_topo, epsg = topocentric_to_grid(poses.centers, rec.reference_lla)
        poses = Poses(poses.names, np.einsum("nij,njk->nik", grid_from_topo, poses.rotations), centers)
        info["reference_lla"] = list(rec.reference_lla)
    else:
        log.warning("%s has no reference_lla: the poses stay in the reconstruction's local frame", rec.path)
        info["frame"] = "local (no reference_lla)"
    cameras = dict(rec.cameras)
    if image_dir is not None:
        files = {p.name: p for p in list_images(image_dir)}
        for cam_id, cam in rec.cameras.items():
            # each camera fitted to the size its shots' images share (map's and check-poses' own decision)
            shots = [files[Path(n).name] for n in poses.names
                     if rec.camera_of_shot[n] == cam_id and Path(n).name in files]
            fitted = camera_for_image_files(cam, shots, rec.path, f"OpenSfM camera {cam_id!r}")
            if fitted != cam:
                cameras[cam_id] = fitted
                info.setdefault("rescaled_cameras", {})[cam_id] = [cam.width, cam.height, fitted.width,
                                                                   fitted.height]
    return poses, cameras, dict(rec.camera_of_shot), epsg, info

def run_opensfm(project: str | Path, out: str | Path, images: str | Path | None = None,
                overwrite: bool = False) -> PosesResult:
    """`sosmatch poses --opensfm PROJECT --out DIR`: an OpenDroneMap / OpenSfM reconstruction as the same
    outputs as `run` (poses.csv in UTM, cameras.txt, a COLMAP model of the poses, poses.json)."""
    from ...database.cameras import pycolmap_camera
    from ...database.opensfm import find_reconstruction

    path = find_reconstruction(project)
    identity = fingerprint({"opensfm": [str(path.resolve()), *_image_identity([path])[0][1:]],
                            "images": _image_identity(list_images(images)) if images else None})
    with open_output_dir(out, "poses", identity, inputs=[path, images], overwrite=overwrite,
                         files=FILES) as taken:
        poses, cameras, cam_of, epsg, info = opensfm_poses(path, images)
        import pycolmap

        ids = {cam_id: k + 1 for k, cam_id in enumerate(sorted(cameras))}
        rec = pycolmap.Reconstruction()
        for cam_id, k in ids.items():
            rec.add_camera_with_trivial_rig(pycolmap_camera(cameras[cam_id], k))
        r_cw, t_cw = poses.cam_from_world()
        for i, name in enumerate(poses.names):
            rec.add_image_with_trivial_frame(pycolmap.Image(name=Path(name).name, camera_id=ids[cam_of[name]],
                                                            image_id=i + 1),
                                             pycolmap.Rigid3d(pycolmap.Rotation3d(r_cw[i]), t_cw[i]))
        sparse = taken.staged("sparse")
        sparse.mkdir()
        rec.write_binary(sparse)
        named = Poses([Path(n).name for n in poses.names], poses.rotations, poses.centers)
        write_text_atomic(taken.staged("poses.csv"), format_poses_csv(named, epsg))
        write_text_atomic(taken.staged("cameras.txt"), format_cameras_txt({k: cameras[c] for c, k in ids.items()}))
        warnings = [] if epsg else ["the OpenSfM reconstruction has no reference_lla: local frame"]
        if info["other_reconstructions"]:
            warnings.append(f"{len(info['other_reconstructions'])} other reconstruction(s) (sizes "
                            f"{', '.join(map(str, info['other_reconstructions']))}) ignored")
        report = {"format": "sosmatch-poses", "version": 1, "source": "opensfm", "opensfm": info,
                  "images": len(poses), "registered": len(poses), "unregistered": [], "epsg": epsg,
                  "crs": f"EPSG:{epsg}" if epsg else "local", "points": 0, "reprojection_px": 0.0,
                  "cameras": {str(k): {"model": cameras[c].model, "width": cameras[c].width,
                                       "height": cameras[c].height, "params": cameras[c].params}
                              for c, k in ids.items()},
                  "camera_of_image": {Path(n).name: ids[cam_of[n]] for n in poses.names}, "warnings": warnings}
        write_text_atomic(taken.staged(RECORD), json.dumps(report, indent=1, default=json_default) + "\n")
        taken.publish(["poses.csv", "cameras.txt", "sparse"], last=RECORD)
        taken.finish()
    return load_result(taken.path)
