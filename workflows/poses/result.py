"""The `poses` output directory: its files, `PosesResult` (read back by `load_result`) and the map inputs of a
result (`map_inputs`); shared helpers of the package."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ...database.landmark_map import POSE_SOURCE_SFM
from ...database.text_input import read_user_json
from ...plugin.errors import InputError
from ...plugin.geometry import Camera, Poses
from ..image_priors import list_images

log = logging.getLogger(__name__)

RECORD = "poses.json"

OUTPUTS = ("poses.csv", "cameras.txt", "sparse", "database.db")
# the files among them and the record: a user's file at one of their names is refused when the folder is taken
FILES = (*(name for name in OUTPUTS if name != "sparse"), RECORD)


@dataclass
class PosesResult:
    """What `run` produced (the files are in `out_dir`)."""

    out_dir: Path
    poses: Poses  # registered images, world_from_camera, sorted by name
    cameras: dict[int, Camera]  # as SfM refined them
    camera_of_image: dict[str, int]
    epsg: int  # 0: local frame
    unregistered: list[str]
    report: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def line(self) -> str:
        """The one-line summary `sosmatch poses` prints."""
        geo = self.report.get("georegistration") or {}
        frame = f"EPSG:{self.epsg}" if self.epsg else "local frame"
        total = self.report.get("images", len(self.poses) + len(self.unregistered))
        text = f"{self.out_dir}: {len(self.poses)} of {total} images registered ({frame}"
        sigma = geo.get("gps_horizontal_sigma_m")  # absent in a local frame (no GPS to measure the noise of)
        if geo.get("gps_noise_measured") is False:  # too few fixes (`HorizontalFit.measured`)
            text += ", GPS noise not measured"
        elif isinstance(sigma, (int, float)):
            text += f", GPS noise {sigma:.2f} m"
        text += f"), {self.report.get('points', 0)} points at {self.report.get('reprojection_px', 0.0):.2f} px"
        if self.warnings:
            text += f"; {len(self.warnings)} WARNING(S), see {RECORD}"
        return text

def load_result(out_dir: str | Path) -> PosesResult:
    """A finished `poses` output directory (poses.csv, cameras.txt, poses.json) as a PosesResult."""
    from ...database.cameras import read_cameras_txt
    from ...database.poses import read_poses_csv

    out_dir = Path(out_dir)
    record = out_dir / RECORD
    report = read_user_json(record, "poses record", redo="re-run `sosmatch poses`")
    poses, epsg = read_poses_csv(out_dir / "poses.csv")
    cameras = read_cameras_txt(out_dir / "cameras.txt")
    return PosesResult(out_dir, poses, cameras, {k: int(v) for k, v in report.get("camera_of_image", {}).items()},
                       epsg, list(report.get("unregistered", [])), report, list(report.get("warnings", [])))

def map_inputs(result: PosesResult, image_dir: Path, source: str) -> Any:
    """`workflows.map.MapInputs` of the registered images (one camera: a folder of several cameras is mapped
    camera by camera, an InputError says so)."""
    from ..map import MapInputs

    if len(result.cameras) != 1:
        _refuse_cameras([f"{c.model} {c.width}x{c.height}" for c in result.cameras.values()], image_dir)
    paths = {p.name: p for p in list_images(image_dir)}
    camera = next(iter(result.cameras.values()))
    return MapInputs([paths[n] for n in result.poses.names], result.poses, camera, result.epsg,
                     {"poses": source, "camera": source, "images": str(image_dir)},
                     warnings=map_warnings(result), refusals=registration_refusals(result.report),
                     pose_source=POSE_SOURCE_SFM, vertical=poses_vertical(result.report))


def map_warnings(result: PosesResult) -> list[str]:
    """The map's verdict's share of a `poses` run (README "Loud, not quiet"): the georegistration's
    and focal length's doubts (`registration_warnings`) and every other warning the record holds (an exposure
    under two names, rounded or lagging GPS, a camera of no sensor's aspect), each once: they doubt the poses the
    map is built on, and on the default path (structure from motion) the map's run.json was their only verdict.
    The record lists the georegistration's among its own, so one text is said once (batch's report reads the
    verdict and skips what it already says: `batch.workflow._session_warnings`)."""
    return with_pose_warnings(registration_warnings(result.report), result.warnings)


def with_pose_warnings(said: list[str], record: Any) -> list[str]:
    """`said` (a map's verdict, as "poses: ..." for its poses' doubts) and each text of a poses record's
    `warnings` (`record`; anything but a list adds nothing) it does not hold yet, as "poses: TEXT"."""
    out = list(said)
    for text in record if isinstance(record, list) else []:
        if isinstance(text, str) and f"poses: {text}" not in out:
            out.append(f"poses: {text}")
    return out


def registration_warnings(report: dict) -> list[str]:
    """The georegistration's and the focal-length check's warnings of a `poses` record (poses.json), as the map's
    verdict says them: what the poses' source found doubtful (GPS fixes left out, a lag corrected or a clock
    offset; the images and EXIF contradicting each other on the focal length, which scales every landmark's
    height) is the map's doubt too; `map_warnings` adds the record's others."""
    if not isinstance(report, dict):
        return []
    geo = report.get("georegistration")
    warnings = list(geo.get("warnings", [])) if isinstance(geo, dict) else []
    focal = report.get("focal_length_warnings", [])
    warnings += focal if isinstance(focal, list) else []
    return [f"poses: {w}" for w in warnings if isinstance(w, str)]


def poses_vertical(report: dict | None) -> tuple[str, float]:
    """(what the poses' vertical rests on, its sigma in deg) as a `poses` record (poses.json) holds them
    (`georegistration.vertical_source` / `vertical_sigma_deg`, or the local frame's); ("", NaN) where the record
    says nothing (a CSV of another origin, an imported model). A map of the poses weighs its ground's tilt against
    a vertical that rests on the nadir assumption alone (`plugin.map_verdict.judge`)."""
    geo = report.get("georegistration") if isinstance(report, dict) else None
    source = geo.get("vertical_source") if isinstance(geo, dict) else None
    sigma = geo.get("vertical_sigma_deg") if isinstance(geo, dict) else None
    return (source if isinstance(source, str) else "",
            float(sigma) if isinstance(sigma, (int, float)) and not isinstance(sigma, bool) else float("nan"))


def registration_refusals(report: dict) -> list[str]:
    """What a `poses` record (poses.json) holds that makes a map of its poses unusable, as the map's verdict says
    it: a lag of the GPS positions behind the images beyond one capture interval, measured and not corrected
    (`Georegistration.lag_beyond_interval`): no trigger latency but positions a whole capture off (a log joined to
    the images one row off, a clock offset), so every camera, and the map, lies up to that far off along the track
    (nu53 H1: 35.8 m, the map published with verdict "ok"). [] for anything else."""
    geo = report.get("georegistration") if isinstance(report, dict) else None
    lag = geo.get("gps_lag") if isinstance(geo, dict) else None
    if not (isinstance(lag, dict) and lag.get("beyond_interval") is True):
        return []
    metres = lag.get("metres")
    far = f"{abs(metres):.1f} m" if isinstance(metres, (int, float)) else "a capture step"
    return [f"poses: the GPS positions and the images disagree along the track by {far}, more than one capture "
            "interval, not corrected: the cameras and the map lie up to that far off their place (positions joined "
            "to the images one row off, or a clock offset between the GPS log and the camera?); fix the log's rows "
            "or times and re-run `sosmatch poses`"]


def recorded_pose_warnings(out_dir: str | Path) -> list[str]:
    """Every warning a `poses` output recorded (OUT_DIR/poses.json `warnings`: images left out or repeated,
    lines off their tags, the georegistration's), for the stages that report on a session (batch); [] without a
    record (a map of given poses). InputError naming poses.json when it does not read or its `warnings` is not a
    list of texts."""
    record = Path(out_dir) / RECORD
    if not record.is_file():
        return []
    report = read_user_json(record, "poses record", redo="re-run `sosmatch poses`")
    said = report.get("warnings", []) if isinstance(report, dict) else None
    if not isinstance(said, list) or not all(isinstance(w, str) for w in said):
        raise InputError("poses record's `warnings` is not a list of texts", record)
    return list(said)


def registration_findings(report: dict | None) -> tuple[list[str], list[str]]:
    """(`map_warnings`, `registration_refusals`) of a `poses` record already read (`poses_record_beside`; None:
    none, nothing to say)."""
    if report is None:
        return [], []
    return (with_pose_warnings(registration_warnings(report), report.get("warnings")),
            registration_refusals(report))


def _refuse_cameras(listing: list[str], image_dir: Path) -> None:
    raise InputError(f"the images come from {len(listing)} cameras ({', '.join(listing)}); map takes one camera: "
                     "put each camera's images in a folder of its own", image_dir)

def _listing(names: Sequence[str], limit: int = 8) -> str:
    return ", ".join(names[:limit]) + (f" ... ({len(names)} in all)" if len(names) > limit else "")
