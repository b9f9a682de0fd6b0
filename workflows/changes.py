"""What changed between two mapped sessions (`sosmatch changes A B --match AB/match.json --out C`).

`run(session_a, session_b, match_json, out_dir)` reads both sessions (landmarks, keyframe poses and cameras,
the segments in their databases), brings B into A's frame with the accepted alignment of match.json (read by
`database.match_io.read_match`) and classifies every landmark of either map as kept, gone, new or unseen
(`sosmatch.plugin.changes.detect_changes`). Everything is read and checked before anything is written, so a bad
input leaves nothing behind; then, atomically, into `out_dir`:
    changes.csv       one row per landmark of either map, and per object either session saw but never mapped
                      (`sosmatch.database.changes_io`)
    changes.geojson   the same as WGS84 points, when A's map is georeferenced (EPSG code)
    changes.png       top view: both sessions' observed areas, kept grey, gone red, new green
    changes.json      counts, the transform, the gate, parameters, inputs, the summary line and the run's
                      warnings (written last: its presence means the run finished;
                      `database.changes_io.read_changes_record` reads it back)
`compute(...)` is the same without writing (batch writes each accepted pair's result into its pair folder).
"""

from __future__ import annotations

import io
import json
import logging
import textwrap
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..database.atomic import write_bytes_atomic, write_text_atomic
from ..database.changes_io import (
    CHANGES_FORMAT,
    changes_feature_collection,
    format_changes_csv,
    parse_changes_record,
)
from ..database.geojson import check_within_crs_area
from ..database.landmark_map import check_two_maps
from ..database.map_loading import session_size_definition, size_definition_disagreement
from ..database.match_io import answer_gate, check_match_maps, read_match
from ..database.match_notes import check_georeferences, imprecise_note, unverified_note
from ..database.output_checks import check_output_dir
from ..database.output_markers import VersionedIdentity, fingerprint, versioned_identity
from ..database.outputs import OutputDir, open_output_dir
from ..database.session_images import compared_images_dirs, recorded_images_dir
from ..database.session_io import SessionFiles, read_map_record, read_session, read_session_observations
from ..plugin import __version__
from ..plugin.changes import (
    GONE,
    KEPT,
    NEW,
    UNSEEN,
    AlignmentSupport,
    ChangeResult,
    SessionObservations,
    counterpart_gate,
    detect_changes,
    implausible_alignment,
    implausible_pair,
    pair_support,
    smallest_mask_area,
)
from ..plugin.errors import InputError
from ..plugin.multisession import Sim3
from ..plugin.params import Params, for_image, params_to_dict
from .changes_images import database_note, image_notes, untested_note

log = logging.getLogger(__name__)

OUTPUT_FILES = ("changes.csv", "changes.geojson", "changes.png", "changes.json")


@dataclass
class ChangesRun:
    """What `compute` found: the verdicts and what they were computed from."""

    result: ChangeResult
    a_from_b: Sim3
    epsg: int
    sources: dict[str, str]
    seconds: float = 0.0
    # the alignment control (`check_alignment`'s rule) at the counterpart gate of the match's own theta_eps
    control: AlignmentSupport | None = None  # A's landmarks against B
    control_gate_m: float | None = None
    control_b: AlignmentSupport | None = None  # ... and B's against A (`pair_support`: both must pass)
    # what `compute` warned of (a result it doubts is no plain success): kept in changes.json, on the plot, and
    # carried into a batch's report
    warnings: list[str] = field(default_factory=list)

    def summary(self) -> str:
        return self.result.summary()


IMAGES_ADVICE = "give --images-a / --images-b"  # `sosmatch changes`'s options; batch says its own


def compute(session_a: str | Path, session_b: str | Path, match_json: str | Path | None, params: Params | None = None,
            a_from_b: Sim3 | None = None, verified: bool = False, images_a: str | Path | None = None,
            images_b: str | Path | None = None, answer_gate_m: float | None = None,
            trust_images: bool = False, images_advice: str = IMAGES_ADVICE) -> ChangesRun:
    """Read, check and classify; nothing is written. The match must be accepted and computed for exactly these
    two maps (`match_io.check_match_maps`). `a_from_b` overrides the match's transform (batch passes its verified
    alignment with `verified=True`, and its match's gate as `answer_gate_m`); `match_json` may then be None.

    Whether the alignment is right has one answer, match's verification on the full maps: a verified alignment
    is refused here only when its counterparts are no more frequent than chance (B displaced); an unverified one
    (a match.json from before the verification stage, or a transform from elsewhere) must also be significant.
    That control runs at the gate of the match that produced the transform (`match_io.answer_gate`, as merge and
    batch run it: `check_alignment`); only without one (a transform given otherwise and no `answer_gate_m`, or a
    match.json that records none) at the configured theta_eps. The classification's counterpart gate is the
    configured theta_eps's (`params.association.distance_tolerance_m`, where it was calibrated).

    A match whose images agree while the two maps' georeferences do not (`match_notes.georeference_note`, the rule
    of `match`, `merge` and `batch`) is refused unless `trust_images` (then said in the warnings): one
    georeference is wrong, or the images agree on another site that looks alike, and changes.geojson would place
    the verdicts by A's. `images_advice`: how the caller's user gives the images when they are not found (batch
    has its own)."""
    params = params or Params()
    t0 = time.perf_counter()
    match = None
    if match_json is not None:
        match = read_match(match_json)
        if not match.accepted or match.transform is None:
            raise InputError("match has no accepted transform: the sessions were not aligned, nothing to compare",
                             match_json)
        verified = verified or (a_from_b is None and match.source == "verified")
        a_from_b = a_from_b or match.transform
    if a_from_b is None:
        raise ValueError("give match_json or a_from_b")
    files_a, files_b = read_session(session_a), read_session(session_b)
    for files in (files_a, files_b):
        if files.is_merged:
            # the evidence of change is each flight's own images and segments, which a merged model keeps
            # neither of (the eleventh sweep: a season map against one of its flights' neighbours claimed 79
            # objects gone on 7.7 ha, 6 of them near any object, at confidence 0.98, exit 0); known by its output
            # marker, so named for a folder that has lost its merge.json too (rev46 D4)
            raise InputError("a merged model (`sosmatch merge`'s output): change detection compares two flights by "
                             "their own images and segments; give the mapped session of a flight", files.path)
    prints = check_two_maps(session_a, session_b, files_a.landmarks, files_b.landmarks)
    for files in (files_a, files_b):
        if not len(files.landmarks):
            raise InputError("landmark map holds no landmarks: nothing to compare", files.path / "landmarks.sosmap")
    if match is not None:
        check_match_maps(match, files_a.landmarks, files_b.landmarks, match_json,
                         names=(str(session_a), str(session_b)))
    tracks = params.changes.unmapped_objects
    warnings = []  # said once every check has passed: a refused run prints its one-line error alone
    if match is not None and (note := check_georeferences(match, files_a.landmarks, files_b.landmarks, match_json,
                                                          trust_images, "compared", "compares them")) is not None:
        warnings.append(f"{session_b}: {note}; compared all the same (--trust-images): changes.geojson is placed by "
                        f"{session_a}'s georeference")
    if match is not None and (note := imprecise_note(match)) is not None:
        warnings.append(f"{match_json}: {note}: objects near the far side of the common area may be compared "
                        "with the wrong partners")
    if (note := size_definition_disagreement(*(session_size_definition(f.path, f.record) for f in (files_a, files_b)))):
        # match warns of it for its search; here the sizes are compared again (rev44 D2: silent before)
        warnings.append(f"{note}; here size_change_m carries that difference, and kept objects whose sizes it "
                        "pushes beyond changes.max_size_difference lose their counterpart (claimed gone or new)")
    if match is not None and not verified and (note := unverified_note(match)) is not None:
        warnings.append(f"{match_json}: {note}: its transform is used only because B's landmarks find "
                        "counterparts in A far more often than by chance; `sosmatch match` again verifies it")
    dirs, lacking = compared_images_dirs((files_a, files_b), (images_a, images_b), params.changes.surface_evidence)
    if lacking:
        missing = " and ".join(f"{'AB'[k]} ({(session_a, session_b)[k]})" for k in lacking)
        warnings.append(f"the images of session {missing} are not available (no run.json recording them, or "
                        f"the directory it records is gone; {images_advice}): no surface evidence, "
                        f"the segments alone decide{untested_note(params.changes)}")
    obs_a = compared_observations(files_a, params, with_tracks=tracks, images_dir=dirs[0])
    obs_b = compared_observations(files_b, params, with_tracks=tracks, images_dir=dirs[1])
    result = detect_changes(obs_a, obs_b, a_from_b, params.changes, params.association.distance_tolerance_m)
    for name, path, obs, other in (("A", session_a, obs_a, session_b), ("B", session_b, obs_b, session_a)):
        if obs.segments is None:
            warnings.append(database_note(result, name, path, other, params.changes))
    for name, path, files, d in (("A", session_a, files_a, dirs[0]), ("B", session_b, files_b, dirs[1])):
        warnings += image_notes(result, name, path, files.path, d, params.changes)
    for name in result.without_relief:
        path = session_a if name == "A" else session_b
        warnings.append(f"the images of {path} (session {name} of the comparison) show no relief at its reference "
                        "places (views of an orthophoto, bare fields, or too coarse for a height?): its objects "
                        f"cannot be told from ground texture, so its changes are claimed without that test"
                        f"{untested_note(params.changes)}")
    for name in result.without_ground_noise:
        path = session_a if name == "A" else session_b
        warnings.append(f"{path} (session {name} of the comparison): no place at ground level to measure "
                        "how its surface heights scatter on bare ground: its claims are not tested for an object "
                        "standing there (expect false changes of moved shadows and re-segmented ground)")
    warnings += sensing_notes(result, str(session_a), str(session_b))
    for name, area, path in (("A", result.observed_a, session_a), ("B", result.observed_b, session_b)):
        if not area.area > 0:
            raise InputError(f"session {name}'s keyframes see no ground (no footprint): nothing to compare", path)
    if not result.common_area.area > 0:
        raise InputError("after alignment the two sessions observed no common ground: the match is wrong or the "
                         "flights do not overlap", match_json or session_b)
    sup = result.support
    if sup is not None and sup.compared == 0:
        raise InputError("none of A's landmarks lies where B's keyframes looked (in view of enough of them to be "
                         "compared): after alignment the flights do not overlap, or B's poses do not look at the "
                         "ground; nothing compared", match_json or session_b)
    # the control at the gate of the association that aligned the maps: with tolerances derived from the maps
    # (theta_eps 8.2 m on NAIP) the configured 2 m finds 1 counterpart in 142 at the true alignment
    tolerance = (answer_gate_m if answer_gate_m is not None
                 else answer_gate(match, params.association.distance_tolerance_m))
    control_gate = counterpart_gate(params.changes, tolerance)
    # the control of the pair, both directions (`implausible_pair`), as merge and batch apply it (`check_alignment`);
    # A's direction at the classification's gate is the classification's own (`sup`), not computed again
    control = None if sup is None else pair_support(obs_a, obs_b, a_from_b, control_gate, params.changes,
                                                    a_side=sup if control_gate == result.tolerance_m else None)
    if control is not None and (why := implausible_pair(control, control_gate, verified)) is not None:
        raise InputError(f"{why}; nothing compared", match_json or session_b)
    fine = () if control is None or control_gate == result.tolerance_m else pair_support(
        obs_a, obs_b, a_from_b, result.tolerance_m, params.changes, a_side=sup)
    for k, name in enumerate("AB"[:len(fine)]):
        if implausible_alignment(fine[k], result.tolerance_m, verified) is None:
            continue
        # the alignment holds, but not at the classification's own gate: its landmarks scatter beyond it, so a
        # kept object has no counterpart there and would be claimed gone (two NAIP maps, theta_eps 8.2 m: 113 gone
        # and 126 new against 7 + 4 kept, 1 counterpart in 141 at 3 m, 17 at 12.4 m)
        raise InputError(
            f"these maps' landmarks scatter beyond the counterpart gate of the change classification: within "
            f"{result.tolerance_m:g} m ({params.changes.tolerance_factor:g} x the configured theta_eps "
            f"{params.association.distance_tolerance_m:g} m) {fine[k].rate:.0%} of {name}'s {fine[k].compared} "
            f"compared landmarks have a counterpart, {fine[k].displaced_rate:.0%} with {'AB'[1 - k]} displaced, "
            f"while at the match's own theta_eps ({tolerance:g} m) {control[k].rate:.0%} do: kept and gone cannot "
            f"be told apart; compare them with --set association.distance_tolerance_m={tolerance:g}; nothing "
            "compared", match_json or session_b)
    sources = {"session_a": str(session_a), "session_b": str(session_b),
               "match": str(match_json) if match_json is not None else "",
               "images_a": str(dirs[0] or ""), "images_b": str(dirs[1] or ""),
               "map_a": prints[0], "map_b": prints[1]}
    epsg = int(files_a.landmarks.epsg)
    if not epsg and files_b.landmarks.epsg:  # the verdicts are placed in A's frame (rev44 D6: no geojson, unsaid)
        warnings.append(f"{session_b} (session B) is georeferenced (EPSG:{files_b.landmarks.epsg}) and {session_a} "
                        "(A) is not: the verdicts are in A's local frame, so no changes.geojson; for one, compare "
                        "them in the other order (`sosmatch match B A`, then `sosmatch changes B A`)")
    if epsg:
        try:  # the same plausibility test as `export`: a local frame stamped with a CRS has no place on Earth
            check_within_crs_area(epsg, files_a.landmarks.positions[:, :2], session_a)
        except InputError as e:
            warnings.append(f"{e}; no changes.geojson (the table and the plot are in A's frame as given)")
            epsg = 0
    for text in warnings:
        log.warning("%s", text)
    control_a, control_b = control or (None, None)
    return ChangesRun(result, a_from_b, epsg, sources, time.perf_counter() - t0, control_a, control_gate,
                      control_b, warnings)


def sensing_notes(result: ChangeResult, session_a: str, session_b: str) -> list[str]:
    """A warning for each session that sees the other's objects so unlike it that their absence weighs less than
    half (`ChangeResult.sensing_a/b`, `evidence.visible_share` < 1/2): its claims of absence are weak."""
    notes = []
    for seen, other, mine, path, other_path in ((result.sensing_a, result.sensing_b, "A", session_b, session_a),
                                                (result.sensing_b, result.sensing_a, "B", session_a, session_b)):
        if seen is None or other is None or not seen.visible < 0.5:
            continue
        name = "B" if mine == "A" else "A"
        notes.append(f"{path} (session {name}): its map holds {other.compared} landmarks over the common area "
                     f"against {mine}'s {seen.compared}; it shows about {100 * seen.shows:.0f} % of {mine}'s "
                     f"landmarks (maps {100 * seen.mapped:.0f} %), against {100 * other.shows:.0f} % of its own "
                     f"that {other_path} shows: the sessions do not see alike (another sensor, low contrast?); "
                     f"claims that {mine}'s objects are absent from it are weak (their weight "
                     f"{seen.visible:.2f} of a session that sees alike)")
    return notes


def compared_observations(session: str | Path | SessionFiles, params: Params, **read: Any) -> SessionObservations:
    """The session as change detection sees it (`read_session_observations`, keywords `read`), with the smallest
    mask its segmentation kept (`SessionObservations.smallest_mask_px`): the one its run.json records (the
    segmentation parameters as scaled to its images and ground resolution), else `params`' scaled to its largest
    camera (a session mapped by an older sosmatch, or a toy one)."""
    files = session if isinstance(session, SessionFiles) else read_session(session)
    obs = read_session_observations(files, **read)
    recorded = ((files.record.get() or {}).get("params") or {}).get("segmentation")  # run.json, read once
    names = ("backend", "min_mask_area_px", "classical_min_area_px")
    if isinstance(recorded, dict) and all(isinstance(recorded.get(k), str if k == "backend" else (int, float))
                                          for k in names):
        seg = [recorded[k] for k in names]
    else:
        cam = max(obs.cameras, key=lambda c: c.width * c.height)
        scaled = for_image(params, cam.width, cam.height).segmentation
        seg = [scaled.backend, scaled.min_mask_area_px, scaled.classical_min_area_px]
    return replace(obs, smallest_mask_px=smallest_mask_area(*seg))


def check_alignment(session_a: SessionFiles, session_b: SessionFiles, a_from_b: Sim3, params: Params, verified: bool,
                    association_tolerance_m: float, where: str | Path, refusing: str) -> None:
    """InputError naming `where` (then `refusing`: what the caller did not do) when `a_from_b` does not bring the
    two sessions' maps together by the control `compute` applies (`plugin.changes.implausible_pair`: the
    counterpart rate of A's landmarks that B's keyframes saw, against B displaced, and of B's that A's keyframes
    saw, against A displaced, each in its own frame: the pair's verdict, whichever is named first; at the gate of
    `association_tolerance_m`, theta_eps of the association that aligned the maps: `match_io.answer_gate`;
    `verified`: match's verification decided the alignment). For a transform used without change detection
    (`merge`: an unverified consensus 181 m off was merged, 6 landmarks fused wrongly, exit 0, where `changes`
    refused it as chance)."""
    obs_a = compared_observations(session_a, params, with_segments=False)
    obs_b = compared_observations(session_b, params, with_segments=False)
    gate = counterpart_gate(params.changes, association_tolerance_m)
    if (why := implausible_pair(pair_support(obs_a, obs_b, a_from_b, gate, params.changes), gate, verified)):
        raise InputError(f"{why}; {refusing}", where)


def png_title(result: ChangeResult, warnings: list[str]) -> str:
    """The plot's title: the summary line, then each warning of the run (a plot read alone must say them)."""
    return "\n".join([textwrap.fill(result.summary(), 110),
                      *(textwrap.fill(f"WARNING: {w}", 110) for w in warnings)])


def changes_png(result: ChangeResult, title: str = "") -> bytes:
    """Top view in A's frame: the observed areas of A and B, kept landmarks grey, gone red, new green (marker
    size grows with the landmark's size; objects a session never mapped as diamonds), unseen ones faint.
    `title`: as given (`png_title`: the summary and the warnings), else the summary line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import shapely

    fig, ax = plt.subplots(figsize=(9, 9), dpi=100)
    for geom, colour, name in ((result.observed_a, "#1f77b4", "observed by A"),
                               (result.observed_b, "#ff7f0e", "observed by B")):
        first = True
        for poly in getattr(geom, "geoms", [geom]):
            if isinstance(poly, shapely.Polygon) and not poly.is_empty:
                x, y = poly.exterior.xy
                ax.fill(x, y, color=colour, alpha=0.08, lw=0)
                ax.plot(x, y, color=colour, lw=0.8, alpha=0.6, label=name if first else None)
                first = False

    def draw(pos: np.ndarray, sizes: np.ndarray, mask: np.ndarray, **kw: Any) -> None:
        if np.any(mask):
            s = 6.0 + 4.0 * np.nan_to_num(sizes[mask], nan=1.0) ** 1.5
            ax.scatter(pos[mask, 0], pos[mask, 1], s=s, **kw)

    a, b = result.a, result.b
    for pos, sizes, verdict in ((result.positions_a, result.sizes_a, a), (result.positions_b, result.sizes_b, b)):
        draw(pos, sizes, verdict.label == UNSEEN, c="#cccccc", alpha=0.5, linewidths=0)
    draw(result.positions_a, result.sizes_a, a.label == KEPT, c="#777777", alpha=0.7, linewidths=0,
         label=f"kept ({a.count(KEPT)} of A, {b.count(KEPT)} of B)")
    draw(result.positions_b, result.sizes_b, b.label == KEPT, c="#777777", alpha=0.7, linewidths=0)
    def ring(pos: np.ndarray, mask: np.ndarray, colour: str) -> None:
        # a change is a few metres on a plot of hundreds: a ring around each makes it visible at a glance
        if np.any(mask):
            ax.scatter(pos[mask, 0], pos[mask, 1], s=220, facecolors="none", edgecolors=colour, linewidths=1.5)

    draw(result.positions_a, result.sizes_a, a.label == GONE, c="#d62728", edgecolors="k", linewidths=0.5,
         label=f"gone ({a.count(GONE)})")
    draw(result.positions_b, result.sizes_b, b.label == NEW, c="#2ca02c", edgecolors="k", linewidths=0.5,
         label=f"new ({b.count(NEW)})")
    ring(result.positions_a, a.label == GONE, "#d62728")
    ring(result.positions_b, b.label == NEW, "#2ca02c")
    for objs, verdict, change, colour in ((result.unmapped_a, result.tracks_a, GONE, "#d62728"),
                                          (result.unmapped_b, result.tracks_b, NEW, "#2ca02c")):
        if verdict is not None:  # objects never mapped (from track pieces): diamonds
            draw(objs.positions, objs.sizes, verdict.label == change, c=colour, marker="D", edgecolors="k",
                 linewidths=0.5, label=f"{change}, never mapped ({verdict.count(change)})")
            ring(objs.positions, verdict.label == change, colour)
    ax.scatter([], [], c="#cccccc", label=f"unseen by the other ({a.count(UNSEEN)} + {b.count(UNSEEN)})")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m] (A's frame)")
    ax.set_ylabel("y [m]")
    ax.set_title(title or textwrap.fill(result.summary(), 110), fontsize=9, loc="left")
    ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _support_record(support: AlignmentSupport | None) -> dict[str, Any] | None:
    return None if support is None else {
        "compared": support.compared, "matched": support.matched, "rate": round(support.rate, 4),
        "displaced_rate": round(support.displaced_rate, 4), "p_value": support.p_value}


def changes_record(run: ChangesRun, params: Params) -> dict[str, Any]:
    """The changes.json document (validated by `changes_io.parse_changes_record`, as its reader does)."""
    res = run.result
    return parse_changes_record({
        "format": CHANGES_FORMAT, "version": __version__, **run.sources,
        "a_from_b": run.a_from_b.to_dict(), "epsg": run.epsg,
        "counts": res.counts(), "common_area_ha": round(float(res.common_area.area) / 1e4, 4),
        "observed_area_ha": {"a": round(float(res.observed_a.area) / 1e4, 4),
                             "b": round(float(res.observed_b.area) / 1e4, 4)},
        "counterpart_gate_m": res.tolerance_m,
        "alignment_support": _support_record(res.support),
        # what the alignment control judged (`compute`): at the gate of the match's own theta_eps
        "alignment_control": None if run.control is None else {"gate_m": run.control_gate_m,
                                                                **_support_record(run.control),
                                                                "b_against_a": _support_record(run.control_b)},
        "params": {"changes": params_to_dict(params.changes),
                   "association.distance_tolerance_m": params.association.distance_tolerance_m},
        "summary": res.summary(), "warnings": list(run.warnings), "seconds": round(run.seconds, 3),
    })


def check_output_entries(out_dir: str | Path) -> None:
    """InputError when a name the outputs take (OUTPUT_FILES) is a directory in `out_dir`: not ours to replace."""
    for name in OUTPUT_FILES:
        path = Path(out_dir) / name
        if path.is_dir() and not path.is_symlink():
            raise InputError("is a directory where `sosmatch changes` writes a file; not replaced (remove it or "
                             "choose another output directory)", path)


def write_outputs(run: ChangesRun, out: OutputDir, params: Params, plot: bool = True) -> list[Path]:
    """Write changes.csv, changes.geojson (georeferenced maps), changes.png and changes.json (last) into the directory
    `out` the caller has taken (`database.outputs.open_output_dir`), through its staging area: outputs of an earlier
    run that this one does not produce (a geojson, a plot) are removed, so the directory never mixes two runs, and
    a file at one of their names that sosmatch did not write there is refused before anything changes (`publish`)."""
    write_text_atomic(out.staged("changes.csv"), format_changes_csv(run.result))
    if run.epsg:
        write_text_atomic(out.staged("changes.geojson"), json.dumps(changes_feature_collection(run.result, run.epsg),
                                                                   separators=(",", ":")) + "\n")
    if plot:
        write_bytes_atomic(out.staged("changes.png"), changes_png(run.result, png_title(run.result, run.warnings)))
    write_text_atomic(out.staged("changes.json"), json.dumps(changes_record(run, params), indent=1) + "\n")
    # the record is removed first and comes back last: a run that fails half-way never leaves an earlier run's
    # record beside its own tables (the marker says it is unfinished; a re-run completes it)
    out.publish(OUTPUT_FILES[:-1], last=OUTPUT_FILES[-1], optional=("changes.geojson", "changes.png"))
    return [out.path / name for name in OUTPUT_FILES if (out.path / name).is_file()]


def output_identity(run: ChangesRun, params: Params, plot: bool) -> VersionedIdentity:
    """What determines the outputs: both maps (content fingerprints), the transform, the images (their content,
    `images_content`) and the parameters (today's identity and earlier versions' of the same output)."""
    return _identity([run.sources["map_a"], run.sources["map_b"]], run.a_from_b,
                     [run.sources["session_a"], run.sources["session_b"]],
                     [run.sources["images_a"], run.sources["images_b"]], params, plot)


def images_content(session: str | Path, images_dir: str | Path | None) -> str:
    """The images of a session in an identity: "" when none were read; else the digests of its keyframe images
    the map records (run.json `keyframe_images`, which `compared_images_dirs` checked the directory against), not
    where they lie, so that a project moved whole is the same comparison (nu37 D1). A map without that record
    (an older sosmatch): the directory's path, as before."""
    if not images_dir:
        return ""
    try:
        digests = (read_map_record(session) or {}).get("keyframe_images")
    except (InputError, AttributeError):
        digests = None
    if isinstance(digests, dict) and digests:
        return "keyframe_images:" + fingerprint(digests)
    return str(images_dir)


def _identity(maps: list[str], a_from_b: Sim3, sessions: list[str | Path], images: list[str | Path | None],
              params: Params, plot: bool) -> VersionedIdentity:
    """`output_identity` of its parts; the identities sosmatch gave the same output until nu37 (the images by the
    path of their directory) are among its earlier ones (`same_as`)."""

    def build(seen: list[str]) -> Any:
        return lambda as_dict: {
            "maps": list(maps), "a_from_b": a_from_b.to_dict(), "changes": as_dict(params.changes), "images": seen,
            "eps": params.association.distance_tolerance_m, "plot": plot}

    return versioned_identity(build([images_content(s, d) for s, d in zip(sessions, images)])).accepting(
        versioned_identity(build([str(d or "") for d in images])))


def _identity_before(session_a: str | Path, session_b: str | Path, match_json: str | Path, params: Params,
                     plot: bool, images_a: str | Path | None, images_b: str | Path | None) -> VersionedIdentity | None:
    """The output identity as `compute` will find it, from its inputs and settings alone (None when a check of
    `compute` refuses them: it says why): checked before the work, so that a refused output directory costs no
    computation (nu37 D1: 5.6 s before the refusal)."""
    try:
        match = read_match(match_json)
        if not match.accepted or match.transform is None:
            return None
        files_a, files_b = read_session(session_a), read_session(session_b)
        prints = check_two_maps(session_a, session_b, files_a.landmarks, files_b.landmarks)
        dirs, _ = compared_images_dirs((files_a, files_b), (images_a, images_b), params.changes.surface_evidence)
    except InputError:
        return None
    return _identity(list(prints), match.transform, [session_a, session_b], dirs, params, plot)


def run(session_a: str | Path, session_b: str | Path, match_json: str | Path, out_dir: str | Path,
        params: Params | None = None, plot: bool = True, overwrite: bool = False,
        images_a: str | Path | None = None, images_b: str | Path | None = None,
        trust_images: bool = False) -> ChangesRun:
    """Classify every landmark of A and B against the other session and write the outputs (module docstring).

    Raises InputError, with nothing written, for a match without an accepted transform, a match of other maps,
    the same session (or map) twice, a map without landmarks, sessions without keyframe poses or ground
    footprints, no common observed ground, or an output directory that is an input or not ours
    (`database.outputs`, checked before any work; `overwrite` replaces a complete changes output of other inputs),
    or a match whose images agree while the maps' georeferences do not, unless `trust_images` (`compute`).
    """
    params = params or Params()
    out_dir = Path(out_dir)
    # the images each session's map records are read too (surface evidence): writing among them is refused
    images = [images_a or recorded_images_dir(session_a), images_b or recorded_images_dir(session_b)]
    check_output_dir(out_dir, "changes", legacy_record="changes.json",
                     inputs=[p for p in (session_a, session_b, match_json, *images) if p is not None],
                     identity=_identity_before(session_a, session_b, match_json, params, plot, images_a, images_b),
                     overwrite=overwrite, files=OUTPUT_FILES)
    check_output_entries(out_dir)
    changes = compute(session_a, session_b, match_json, params, images_a=images_a, images_b=images_b,
                      trust_images=trust_images)
    with open_output_dir(out_dir, "changes", output_identity(changes, params, plot),
                         inputs=[session_a, session_b, match_json], overwrite=overwrite,
                         legacy_record="changes.json", files=OUTPUT_FILES) as out:
        write_outputs(changes, out, params, plot)
        out.finish()
    log.debug("%s", changes.summary())  # the command prints it (rev44 D4: twice at INFO)
    return changes
