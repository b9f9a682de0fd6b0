"""What the inputs of a session compared by `sosmatch changes` put in doubt. Its images: a flight heavily
JPEG-compressed (`plugin.jpeg_quality`) or motion-blurred along its track (`plugin.motion_blur`) makes gone and new
claims of artefacts, at confidences that cannot show it (they are calibrated on the pair's kept landmarks, which such
images leave alike); `image_notes` names those claims. Read from the session's run.json (`sosmatch map` records
both), else, for the compression, from its images' headers. Its database (`database_note`): without its
segments, claims against it rest on its map alone. Images missing or without relief (`untested_note`): claims
untested for an object standing there.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..database.session_io import read_map_record
from ..plugin.changes import GONE, LOW_CONFIDENCE, NEW, NO_EVIDENCE, ChangeResult
from ..plugin.errors import InputError
from ..plugin.jpeg_quality import FlightCompression
from ..plugin.params.changes import ChangeParams


def image_notes(result: ChangeResult, name: str, path: str | Path, session: Path, images_dir: Path | None,
                params: ChangeParams) -> list[str]:
    """The warnings for session `name` (A or B; `path` as the user gave it, `session` its directory, `images_dir`
    its images or None) of the comparison `result`: its compression and its smear, each naming the claims it puts
    in doubt; [] when neither is beyond its limit or there is no claim."""
    notes = [compression_note(result, name, path, session_compression(session, images_dir), params.min_jpeg_quality),
             blur_note(result, name, path, session_smear(session), params.max_motion_smear_px)]
    return [n for n in notes if n]


def session_compression(session: Path, images_dir: Path | None) -> FlightCompression | None:
    """A mapped session's JPEG compression: as its run.json records it (`quality.images.jpeg`, `sosmatch map`),
    else measured on the headers of its images directory (`plugin.jpeg_quality`; maps made before it was
    recorded); None when neither is at hand."""
    from ..plugin.jpeg_quality import flight_compression

    try:
        rec = (read_map_record(session) or {})["quality"]["images"]["jpeg"]
        q = rec["quality"]
        return FlightCompression(None if q is None else float(q), rec["lowest"], int(rec["samples"]),
                                 int(rec["jpeg"]))
    except (InputError, ValueError, KeyError, TypeError):
        pass
    if images_dir is None:
        return None
    from ..database.images import image_files

    return flight_compression(image_files(images_dir))


def compression_note(result: ChangeResult, name: str, path: str | Path, compression: FlightCompression | None,
                     min_quality: float) -> str:
    """The warning for a session compressed below `min_quality` (`ChangeParams.min_jpeg_quality`), naming the
    claims it puts in doubt, "" otherwise. Every gone and new claim rests on both sessions' images: on the
    images of the session that is said to lack the object (its segments do not show it) and on those of the
    session that mapped it (its landmark is an object). Heavy compression fails both: it smooths small objects out
    of the segments and cuts the ground into block-shaped segments that track as landmarks. The confidences are
    calibrated on the pair's own kept landmarks, which compression leaves alike, so they cannot show it."""
    if compression is None or not compression.below(min_quality):
        return ""
    if not (doubted := _doubted_claims(result)):
        return ""
    return (f"the images of {path} (session {name} of the comparison) are heavily JPEG-compressed (quality "
            f"{compression.quality:.0f}, below {min_quality:g}): compression hides small objects from its segments "
            f"and cuts its ground into block-shaped segments that are mapped as objects, so its claims may be "
            f"artefacts, not changes: {doubted}"
            + f" (a pair of world 7 where nothing changed made 1-11 such claims at confidences up to 0.999 at "
              f"qualities 15-60, none at 75 and 88); compare images written at quality {min_quality:g} or more")


def _doubted_claims(result: ChangeResult) -> str:
    """The gone and new claims a session's images put in doubt, as the notes name them ("2 landmark(s) (gone A#3,
    new B#7) and 1 object(s) never mapped"; the first 8 shown); "" when there is none."""
    claims = [f"gone A#{i}" for i in np.flatnonzero(result.a.label == GONE)] + \
        [f"new B#{i}" for i in np.flatnonzero(result.b.label == NEW)]
    unmapped = sum(t.count(c) for t, c in ((result.tracks_a, GONE), (result.tracks_b, NEW)) if t is not None)
    if not claims and not unmapped:
        return ""
    shown = ", ".join(claims[:8]) + (", ..." if len(claims) > 8 else "")
    return f"{len(claims)} landmark(s) ({shown})" + (f" and {unmapped} object(s) never mapped" if unmapped else "")


def session_smear(session: Path) -> float:
    """A mapped session's smear along its track (working px) as its run.json records it
    (`quality.images.motion_smear_px`, `plugin.motion_blur`); NaN when not recorded (maps made before it was)."""
    try:
        v = (read_map_record(session) or {})["quality"]["images"]["motion_smear_px"]
        return float("nan") if v is None else float(v)
    except (InputError, ValueError, KeyError, TypeError):
        return float("nan")


def blur_note(result: ChangeResult, name: str, path: str | Path, smear_px: float, max_smear_px: float) -> str:
    """The warning for a session smeared along its track beyond `max_smear_px` (`ChangeParams.max_motion_smear_px`),
    naming the claims it puts in doubt, "" otherwise. A smear merges small objects with their surroundings (gone
    from its segments) and splits or displaces others along the track, as compression does (`compression_note`);
    the confidences, calibrated on the pair's kept landmarks, cannot show it."""
    if not (max_smear_px > 0 and np.isfinite(smear_px) and smear_px > max_smear_px):
        return ""
    if not (doubted := _doubted_claims(result)):
        return ""
    return (f"the images of {path} (session {name} of the comparison) are motion-blurred (the ground smeared "
            f"{smear_px:.1f} working px along the track, above {max_smear_px:g}): the smear hides small objects "
            f"from its segments and merges or splits others, so its claims may be artefacts, not changes: {doubted}"
            + " (world 7, nothing changed, a 12 px blur along the track (7.5 working px): 4 false claims at high "
              "confidence); compare a flight with a shorter exposure or a slower speed")


def untested_note(params: ChangeParams) -> str:
    """The end of the warning that claims could not be tested for an object standing there (no images, or images
    without relief): what that does to their confidences and to `--min-confidence`; "" when it does nothing."""
    rate = params.untested_object_rate
    if rate >= 1.0:
        return ""
    held = (f"so at --min-confidence {params.min_confidence:g} none is reported; lower it below {rate:g} to list "
            "the candidates" if params.min_confidence > rate else "so every claim is a candidate to check")
    return (f", and they cannot tell a change of looks (a moved shadow, ground texture) from an object that went: "
            f"each claim's confidence is P(absent | segments) x {rate:g} (changes.untested_object_rate, the share "
            f"of such claims on an object), {held}")


def database_note(result: ChangeResult, name: str, path: str | Path, other: str | Path, params: ChangeParams) -> str:
    """The warning for session `name` (A or B; `path` as the user gave it) compared without its database.db: its
    segments cannot show the other session's (`other`) objects, so a claim that one of them went from it (gone of
    A's landmarks against B, new of B's against A) rests on its map lacking the landmark alone; the confidence is
    then the probability of absence given how often that map holds landmarks like it (`plugin.changes.verdict`).
    Says the highest such confidence and how many claims pass `min_confidence` (rev44 D3: none could, unsaid)."""
    verdict, change = (result.a, GONE) if name == "B" else (result.b, NEW)
    judged = np.isin(verdict.evidence, (NO_EVIDENCE, LOW_CONFIDENCE)) | (verdict.label == change)
    top = float(np.max(verdict.confidence[judged])) if np.any(judged) else 0.0
    claimed = verdict.count(change)
    held = (f"the highest here is {top:.2f}, below --min-confidence {params.min_confidence:g}: no {change} claim "
            "comes from it (lower it to list the candidates)" if not claimed else
            f"{claimed} {change} claim(s) reach --min-confidence {params.min_confidence:g} (highest {top:.2f})")
    return (f"{path} (session {name} of the comparison) has no database.db: its segments cannot say whether "
            f"{other}'s objects are there, so a {change} claim rests only on its map lacking the landmark; its "
            "confidence is the probability of absence given how often that map holds landmarks like it (1 / (2 - p), "
            "p the pair's re-observation rate, held out; times changes.untested_object_rate when nothing tested an "
            f"object standing there), {held}; map the session again (or copy its database.db back) for its segments' "
            "evidence")
