"""Poses against what the images show: the image I/O around `plugin.pose_check`, for `sosmatch map` (a stage of
every map) and `sosmatch check-poses` (poses a user brings: a pose CSV, a COLMAP model, an OpenSfM project, or
the images' own EXIF/XMP tags).

Only the images of the chosen pairs are read (at most ~`pose_check.max_pairs` x 1.5 of them, whatever the
flight's length), once each, in grey, and their features are computed at `pose_check.max_image_side_px`.
`check` returns the figures; `run` also writes them (`pose_check.json`, atomically) and raises `PosesRefused`
(one line, exit 2 on the command line) when the poses contradict the images.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..database.exif import orientation_note, read_orientation
from ..plugin.errors import InputError
from ..plugin.geometry import Camera, Poses
from ..plugin.image_matching import OrbFeatures
from ..plugin.map_verdict import Verdict
from ..plugin.params import Params, PoseCheckParams, for_image
from ..plugin.pose_check import PoseCheck, check_poses, judge_poses

if TYPE_CHECKING:
    from ..database.images import Levels
    from ..database.output_files import OutputFiles
    from ..database.output_markers import VersionedIdentity
    from ..plugin.pose_check.gps import GpsComparison

log = logging.getLogger(__name__)


class PosesRefused(InputError):
    """The poses contradict the images (`plugin.pose_check.judge_poses`); the message says how."""


def image_features(paths: Sequence[Path], camera: Camera, params: PoseCheckParams,
                   white: Levels | int | None = None) -> Callable[[int], OrbFeatures]:
    """`features(i)`: ORB features of image `paths[i]` at the working size (read on demand; an unreadable image or
    one of another size than the camera is an InputError naming it), at the flight's white level (`white`; None:
    found here, `database.flight_levels.flight_white_level`)."""
    from ..database.flight_levels import flight_white_level
    from ..database.images import read_image
    from ..plugin.image_matching import orb_features

    white = flight_white_level(paths) if white is None else white

    def features(i: int) -> OrbFeatures:
        image = read_image(paths[i], white)
        if image.shape[:2] != (camera.height, camera.width):
            raise InputError(f"image is {image.shape[1]}x{image.shape[0]} but the camera is {camera.width}x"
                             f"{camera.height}", paths[i])
        return orb_features(image, params.max_features, params.max_image_side_px)

    return features


# the settings the check reads (the identity of check-poses' outputs, `check_to_file`): its own section, and the
# tracker's epipolar gate that it judges the poses against, scaled to the image by `image.reference_size_px`
# (`gate_px`). Until fix81 the identity held every setting, so a mapping default that changed (fix76:
# tracking.truncation_aware) refused every earlier check-poses output; a setting the check comes to read goes here.
CHECK_READS = ("pose_check", "tracking.epipolar_margin_px", "image.reference_size_px")


def gate_px(params: Params, camera: Camera) -> float:
    """The tracker's epipolar gate for this camera's image size (the pixel limits scale with the image)."""
    return float(for_image(params, camera.width, camera.height).tracking.epipolar_margin_px)


# at most this many images' EXIF is read for their GPS fixes (evenly over the flight): the scale and the offset
# are measured over the flight's extent, which a few hundred fixes span as well as thousands
MAX_GPS_IMAGES = 300


def gps_fixes(image_paths: Sequence[Path], epsg: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(indices, fixes, fixes in the poses' CRS): up to MAX_GPS_IMAGES images spread over `image_paths` and their
    EXIF GPS positions (K,2) in the UTM zone of their median fix, where lengths are ground metres, and for `epsg`
    other than 0 (georeferenced poses) also in EPSG:`epsg`'s grid (else None); NaN where an image has no fix (or its
    EXIF cannot be read: the images are read and named later, where their pixels are needed)."""
    from ..database.exif import read_image_metadata
    from ..plugin.geodesy import geographic_to_grid, utm_epsg
    from .image_positions import median_position

    idx = np.unique(np.linspace(0, len(image_paths) - 1, min(len(image_paths), MAX_GPS_IMAGES)).round().astype(int))
    latlon = np.full((len(idx), 2), np.nan)
    for k, i in enumerate(idx):
        try:
            meta = read_image_metadata(image_paths[i])
        except (InputError, OSError, ValueError):
            continue
        if meta.has_gps:
            latlon[k] = meta.latitude, meta.longitude
    has = np.all(np.isfinite(latlon), axis=1)

    def grid(code: int) -> np.ndarray:
        out = np.full((len(idx), 2), np.nan)
        if has.any():
            east, north, _ = geographic_to_grid(latlon[has, 0], latlon[has, 1], code)
            out[has] = np.column_stack([east, north])
        return out

    own_zone = utm_epsg(*median_position(latlon[has, 0], latlon[has, 1])) if has.any() else 0
    return idx, grid(own_zone), (grid(epsg) if epsg else None)


def gps_comparison(image_paths: Sequence[Path], poses: Poses, epsg: int) -> GpsComparison | None:
    """The camera centres of `poses` against the images' own GPS fixes (`plugin.pose_check.gps.compare_with_gps`;
    `epsg`: the poses' CRS, 0 for a local frame). Reads only the EXIF of at most MAX_GPS_IMAGES images."""
    from ..plugin.pose_check.gps import compare_with_gps

    idx, fixes, crs_fixes = gps_fixes(image_paths, epsg)
    return compare_with_gps(poses.centers[idx], fixes, crs_fixes, index=idx)


def refuse_by_gps(image_paths: Sequence[Path], poses: Poses, epsg: int, params: PoseCheckParams,
                  source: str | Path) -> GpsComparison | None:
    """The GPS part of the pose check before any work (`sosmatch map`: before the images are segmented): raises
    PosesRefused naming `source` (the pose file) when the images' GPS refuses the poses (a unit that is not the
    metre, a mirrored frame). A map on such poses is no map at all, and its segmentation cost minutes to hours
    on a long flight before the refusal came. Returns the comparison, for `check` to reuse."""
    from ..plugin.pose_check.verdict import judge_gps

    if len(image_paths) != len(poses):
        raise ValueError(f"{len(image_paths)} images for {len(poses)} poses")
    gps = gps_comparison(image_paths, poses, epsg)
    verdict = judge_gps(gps, params)
    if verdict.refusals:
        raise PosesRefused("poses refused: " + "; ".join(verdict.refusals), source)
    return gps


def check(image_paths: Sequence[Path], poses: Poses, camera: Camera, params: Params,
          gate: float | None = None, epsg: int | None = None,
          gps: GpsComparison | None = None, white: Levels | int | None = None,
          remedy: str = "") -> tuple[PoseCheck, Verdict]:
    """The figures of `poses` (in the order of `image_paths`, capture order) against the images, and their
    verdict. `gate`: the tracker's epipolar gate in pixels of these images (None: `gate_px(params, camera)`;
    the map passes its own, as its parameters are already scaled to the image). `epsg`: the poses' CRS (0: a
    local frame); given, the camera centres are also compared with the images' own GPS fixes
    (`gps_comparison`: the poses' unit, and their georeference in that CRS), unless `gps` brings that
    comparison already made (`refuse_by_gps`). `white`: as `image_features`'. `remedy`: `judge_poses`'."""
    from dataclasses import replace

    if len(image_paths) != len(poses):
        raise ValueError(f"{len(image_paths)} images for {len(poses)} poses")
    result = check_poses(poses, camera, image_features(list(image_paths), camera, params.pose_check, white),
                         params.pose_check, gate_px(params, camera) if gate is None else float(gate))
    if gps is None and epsg is not None:
        gps = gps_comparison(image_paths, poses, epsg)
    result = replace(result, gps=gps)
    verdict = judge_poses(result, params.pose_check, poses.names, remedy)
    return result, verdict


@dataclass
class CheckResult:
    """What `run` found and wrote."""

    check: PoseCheck
    verdict: Verdict
    out: Path | None

    def summary(self) -> dict:
        """The verdict and the flight's figures without the per-pair table (for the map's run.json)."""
        figures = {k: v for k, v in self.check.to_dict().items() if k not in ("pairs", "pairs_columns")}
        return {"verdict": _verdict_record(self.verdict), "figures": figures,
                "record": self.out.name if self.out is not None else None}

    def line(self) -> str:
        status = "ok" if self.verdict.ok else "REFUSED"
        text = f"{status}: {self.check.line()}"
        if self.verdict.refusals:  # why (a refusal raised says it itself; --warn-only printed the figures alone, rev41)
            text += f"; {'; '.join(self.verdict.refusals)}"
        if self.verdict.warnings:
            text += f"; WARNING: {'; '.join(self.verdict.warnings)}"
        return text


FORMAT = "sosmatch-pose-check"


def _verdict_record(verdict: Verdict) -> dict:
    return {"status": "ok" if verdict.ok else "refused", "refusals": list(verdict.refusals),
            "warnings": list(verdict.warnings)}


def write_disabled(out: str | Path) -> None:
    """The record of a check that was switched off (`pose_check.enabled=false`)."""
    from ..database.atomic import write_text_atomic

    write_text_atomic(Path(out), json.dumps({"format": FORMAT, "version": 1, "verdict": {"status": "disabled"}})
                      + "\n")


def run(image_paths: Sequence[Path], poses: Poses, camera: Camera, params: Params, out: str | Path | None = None,
        refuse: bool = True, sources: dict | None = None, gate: float | None = None,
        files: OutputFiles | None = None, epsg: int | None = None, gps: GpsComparison | None = None,
        white: Levels | int | None = None, remedy: str = "", input_warnings: Sequence[str] = ()) -> CheckResult:
    """Check the poses (`check`), write the figures to `out` (JSON, atomically; None: nothing written) and raise
    PosesRefused (after writing) when they contradict the images and `refuse` is on. `files`: the OutputFiles
    that `out` is written through (`check_to_file`, a user's file); without it `out` lies in a directory the
    caller owns (the map's output). `epsg`, `gps`, `white`, `remedy`: as `check`'s. `input_warnings`: what reading
    the inputs found (`check-poses`: the copies `map.inputs.distinct_images` left out), logged where found; they
    lead the verdict's warnings in the record and the result's line."""
    from ..database.atomic import write_text_atomic

    result, verdict = check(image_paths, poses, camera, params, gate, epsg, gps, white, remedy)
    if result.fixed_in_frame_text:  # no fault of the poses, but the user should know what the images carry
        log.warning("pose check: %s", result.fixed_in_frame_text)
    for warning in verdict.warnings:
        log.warning("%s", warning)
    if input_warnings:
        verdict = Verdict(list(verdict.refusals), [*input_warnings, *verdict.warnings])
    if out is not None:
        out = Path(out)
        record = {"format": FORMAT, "version": 1, "inputs": sources or {},
                  "verdict": _verdict_record(verdict),
                  "pose_check": result.to_dict([p.name for p in map(Path, image_paths)]),
                  "images": [Path(p).name for p in image_paths],
                  "params": {k: getattr(params.pose_check, k) for k in params.pose_check.__dataclass_fields__}}
        text = json.dumps(record, indent=1) + "\n"
        if files is not None:
            files.write(out, text)
        else:
            write_text_atomic(out, text)
    if verdict.refusals and refuse:
        # the error names the poses, the input that is wrong (their source as `load_inputs` recorded it), and
        # says where the figures are
        where = f" (figures in {out})" if out is not None else ""
        # pixels stored turned against their poses refuse as a drift and a tilt (nu53: Orientation 3 frames, "64 m
        # drift, 61 deg tilt"): a tag that says the files are turned is named with the refusal
        note = orientation_note([read_orientation(p) for p in image_paths])
        raise PosesRefused("poses refused: " + (f"{note}; " if note else "")
                           + "; ".join(r.removeprefix("poses vs images: ") for r in verdict.refusals) + where,
                           (sources or {}).get("poses") or Path(image_paths[0]).parent)
    return CheckResult(result, verdict, out)


def check_identity(sources: dict, names: list[str], params: Params) -> VersionedIdentity:
    """The identity of a check-poses output: its inputs (`sources`, the images' `names`) and the settings the check
    reads (`CHECK_READS`). A file of an earlier sosmatch (whose identity held every setting, in any version) is this
    one when made with these settings and the others as given or at rest (`read_settings_identity`)."""
    from ..database.output_markers import read_settings_identity

    return read_settings_identity(lambda settings: {"sources": sources, "images": names, "params": settings},
                                  params, CHECK_READS)


def check_to_file(image_paths: Sequence[Path], poses: Poses, camera: Camera, params: Params, out: str | Path,
                  refuse: bool = True, sources: dict | None = None, overwrite: bool = False,
                  epsg: int | None = None, input_warnings: Sequence[str] = ()) -> CheckResult:
    """`run` with its figures written to a user's file `out` (`sosmatch check-poses --out`): checked before any
    work by `database.output_files.OutputFiles` (never an input such as the pose file, never a file sosmatch did not
    write; one of this command's made from other inputs or settings is replaced only with `overwrite`)."""
    from ..database.output_files import OutputFiles

    sources = sources or {}
    inputs = [Path(v) for v in sources.values() if v] + sorted({Path(p).parent for p in image_paths})
    identity = check_identity(sources, [Path(p).name for p in image_paths], params)
    files = OutputFiles([out], "check-poses", identity, inputs=inputs, overwrite=overwrite)
    return run(image_paths, poses, camera, params, out, refuse=refuse, sources=sources, files=files, epsg=epsg,
               input_warnings=input_warnings)
