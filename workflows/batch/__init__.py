"""`sosmatch batch FLIGHTS_DIR --out OUT`: map every flight, match session pairs, merge connected groups.

Stages, each a set of independent tasks run by an executor (`sosmatch.workflows.executors`: local worker
processes, or a Dask cluster):
1. discovery: one sub-folder of FLIGHTS_DIR per flight (`discover_flights`), recognised as
   - "mapped": already a mapped session (sparse/, landmarks.sosmap, landmarks.csv): used as it is;
   - "synth": a `sosmatch synth` session (session.json, poses.csv, images/, cameras.txt);
   - "poses": images (in images/ or the folder itself) with a pose file poses.csv (and cameras.txt);
   - "opensfm": images with an OpenDroneMap / OpenSfM project's opensfm/reconstruction.json: its poses and
     cameras (converted to UTM, `sosmatch.workflows.poses.opensfm_poses`);
   - "images": a folder of photos and no pose file: poses and cameras by COLMAP's structure from motion,
     georegistered on their GPS (`sosmatch.workflows.poses`; kept in OUT/sessions/NAME/poses).
2. map: each flight -> OUT/sessions/NAME (`sosmatch.workflows.map`);
3. match: every pair of mapped sessions, or with `nearest=k` only pairs where one session is among the k
   nearest of the other (by mean camera position; needs all sessions in one frame: same EPSG code, or the
   same local frame; a session in a local frame of its own, `pairs.own_frame`, is paired with every other), and
   then also each flight with the flight flown before and the one after it among those
   that overlap it (by the EXIF capture time of its images, where they have one: `pairs.pairs_chosen_by`; the
   flights of one site all overlap, and consecutive surveys are the comparisons a site manager wants)
   -> OUT/pairs/A__B/match.json (`sosmatch match`, which, unless BatchOptions.verify is off,
   checks every window hypothesis on the FULL maps and refines the best supported one:
   `plugin.verification.verify_search`); its answer's decision, transform and associations
   (`database.match_io.read_match`) are what the graph and the merge use. Why verify: across seasons one window
   pair's |S| is no larger for a true hypothesis than for chance ones, and one window's 8-20 inliers give a noisy
   rotation; see BENCHMARKS.md, Multi-session;
4. session graph: sessions are nodes, accepted pairs are edges carrying a_from_b and |S|; accepted pairs
   that contradict others linking the same groups are left out, and an imprecise answer that no other pair
   corroborates (`plugin.multisession.consistent_edges`; the pair's `left_out` says why); each connected
   group is brought into the frame of its best-connected session (georeferenced sessions first; in a batch run
   again, e.g. with flights added, the previous run's reference while it is in the group, so the merged model
   keeps its frame and folder: `graph.previous_references`) along a maximum spanning tree
   (`sosmatch.plugin.multisession.spanning_transforms`) and merged (`sosmatch.workflows.merge.merge_sessions`)
   -> OUT/merged/REFERENCE/;
5. changes (BatchOptions.changes, on by default): every accepted pair in the graph is compared object by object
   with its alignment (`sosmatch.workflows.changes`) -> OUT/pairs/A__B/changes/ (changes.csv, .geojson when
   georeferenced, .png, .json); its counts (changes.json `counts`, `ChangeResult.counts()`: landmarks gone, new,
   kept and unseen of A and of B, objects never mapped gone and new) go into the pair's row
   (`workflow._changes_record`), their sums into the one-line summary in `sosmatch changes`'s words
   (`plugin.changes.counts_summary`);
6. report: OUT/report.json, OUT/report.md (a table per session and per pair), OUT/session_graph.png.

Resume: every finished task writes OUT/state/STAGE/KEY.json atomically as it finishes (`state.run_stage`),
holding a fingerprint of its inputs
(a flight's contents, the parameters its stage reads (`plugin.params.mapping_params` for a map), upstream
fingerprints) and its result (paths relative to OUT, so a moved OUT resumes, and a moved flights folder too).
A re-run skips tasks whose state matches and whose outputs still exist, so an interrupted batch continues
where it stopped; changing parameters redoes what they affect. Folders of OUT that belong to no flight or group
of the run (flights removed since) are named in the report (`BatchReport.stale_outputs`), not deleted.
A failing task is reported with its error
(traceback in OUT/logs/), the tasks that need its output are reported as skipped, and every other task goes
on. `BatchReport.ok` (and the command's exit code) says whether anything failed; `BatchReport.status` ("ok" only
without failures and warnings) and `warnings` what the sessions' maps, the pairs' matches, the alignment control
and change detection warned of, each named by its session or pair (read from their records after every stage, so
a resumed batch says them again).
"""

from __future__ import annotations

from .discovery import PAIR_SEP, Flight, classify_flight, discover_flights
from .report import BatchReport, pair_warnings, plot_session_graph, session_warnings, write_report
from .state import StateStore
from .tasks import changes_task, map_task, merge_task, pair_task, summarise_match
from .workflow import BatchOptions, run

__all__ = [
    "PAIR_SEP", "BatchOptions", "BatchReport", "Flight", "StateStore", "changes_task", "classify_flight",
    "discover_flights",
    "map_task", "merge_task", "pair_task", "pair_warnings", "plot_session_graph", "run",
    "session_warnings", "summarise_match", "write_report",
]
