"""What `sosmatch evaluate` refuses before any work: the methods it knows, option values that make no evaluation,
a session scored against itself or a map that is not one, and a --sweep-floor with nothing to extend."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from ...database.landmark_map import check_two_maps, read_landmark_map
from ...database.output_markers import check_finished
from ...database.session_io import check_session_usable
from ...plugin.association.hypotheses import MIN_LANDMARKS_TO_ALIGN
from ...plugin.errors import InputError
from .ground_truth import _map_arrays

# the methods evaluate scores (`run(methods=...)`, `--methods`)
METHODS = ("sosmatch", "orb_ransac", "sift_ransac")


def _check_sweep_floor(sweep_floor: int | None, theta_s: int) -> None:
    """A floor above the search's theta_S (derived per pair, so known only once the search has run) would change
    nothing: the curve already starts at theta_S (nu45: `--sweep-floor 100` was ignored silently)."""
    if sweep_floor is not None and sweep_floor > theta_s:
        raise InputError(f"--sweep-floor {sweep_floor} is above this pair's theta_S ({theta_s}, where the curve "
                         "already starts): a floor only extends the curve below theta_S; give a smaller one or "
                         "leave it out")


def check_options(ground_height: float, sweep_floor: int | None, repeats: int | None, max_observers: int | None,
                  baseline_threads: int, methods: Sequence[str] = METHODS, match_dir: str | Path | None = None) -> None:
    """Refuse (one-line InputError naming the option) values that make no evaluation. Before: --max-observers 0
    left every landmark without an observer and scored F1 0.000 'limited by front end' with exit 0, a negative
    one sliced observers off the wrong end, a NaN ground height gave NaN footprints, and --repeats / --sweep-floor
    / --baseline-threads below their meaning were taken silently; --sweep-floor and a given --repeats (`repeats`
    not None; None: `DEFAULT_REPEATS`) are refused where no search of evaluate's own runs (they were ignored)."""
    if not math.isfinite(ground_height) or abs(ground_height) > 1e5:
        raise InputError(f"--ground-height must be a finite height in metres (within 100 km), got {ground_height!r}")
    if max_observers is not None and max_observers < 1:
        raise InputError(f"--max-observers must be at least 1 (or left out: every observer), got {max_observers}")
    if sweep_floor is not None and sweep_floor < 2:
        raise InputError(f"--sweep-floor must be at least 2 (the smallest theta_S), got {sweep_floor}")
    if sweep_floor is not None and ("sosmatch" not in methods or match_dir is not None):
        raise InputError("--sweep-floor sets the floor of evaluate's own sosmatch search: " + (
            "a --match file is scored with the hypotheses its search kept" if match_dir is not None else
            "give --methods sosmatch (or leave --sweep-floor out)"))
    if repeats is not None and repeats < 1:
        raise InputError(f"--repeats must be at least 1, got {repeats}")
    if repeats is not None and ("sosmatch" not in methods or match_dir is not None):
        raise InputError("--repeats times evaluate's own sosmatch search: " + (
            "a --match file is scored with the search time it records" if match_dir is not None else
            "give --methods sosmatch (or leave --repeats out)"))
    if baseline_threads < 0:
        raise InputError(f"--baseline-threads must be 0 (one per core) or more, got {baseline_threads}")


def check_two_sessions(session_a: Path, session_b: Path, map_a: str | Path | None, map_b: str | Path | None,
                       with_maps: bool) -> None:
    """InputError before any work when the pair is one session (by path), or (`with_maps`) when a map is one that
    `sosmatch map` refused or has not finished, or the two maps are one map or copies (`check_two_maps`): a
    session scored against itself came out as a perfect F1 1.000, a refused map as F1 0 "limited by the front
    end"; `match` refuses both."""
    if session_a.resolve() == session_b.resolve():
        raise InputError("A and B are the same session: nothing to evaluate (give the sessions of two flights)",
                         session_b)
    if not with_maps:
        return
    maps = _map_dirs(session_a, session_b, map_a, map_b)
    for m in maps:
        check_finished(m)  # a killed map leaves only its staging: say so, not "no landmarks.csv"
        if (m / "landmarks.sosmap").is_file():
            check_session_usable(m)
    if all((m / "landmarks.sosmap").is_file() for m in maps):
        check_two_maps(maps[0], maps[1], *(read_landmark_map(m / "landmarks.sosmap") for m in maps), "evaluate")


def _map_dirs(session_a: Path, session_b: Path, map_a: str | Path | None,
              map_b: str | Path | None) -> tuple[Path, Path]:
    """The mapped sessions the sosmatch method scores: `map_a` / `map_b`, else the session directories."""
    return (Path(map_a) if map_a is not None else session_a, Path(map_b) if map_b is not None else session_b)


def check_sweep_floor_maps(sweep_floor: int | None, maps: Sequence[Path]) -> None:
    """InputError naming the map, before any work, when a --sweep-floor is given and a map has fewer landmarks than
    a transform needs: no search runs (the method claims nothing, an honest zero), so there is no curve for a floor
    to extend (it was ignored silently, exit 0). The other refusals of the floor: `check_options` (with --match or
    without the sosmatch method, which `run` checks first) and `_check_sweep_floor` (above theta_S)."""
    if sweep_floor is None:
        return
    for m in maps:
        if not (m / "landmarks.csv").exists():
            continue  # not a mapped session: `_evaluate` says so
        n = len(_map_arrays(m)[0])
        if n < MIN_LANDMARKS_TO_ALIGN:
            raise InputError(f"--sweep-floor {sweep_floor}: this map has {n} landmark(s), fewer than the "
                             f"{MIN_LANDMARKS_TO_ALIGN} a transform needs, so no search runs and there is no curve "
                             "for a floor to extend; leave --sweep-floor out", m)
