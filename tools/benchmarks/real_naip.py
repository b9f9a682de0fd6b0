"""NAIP checks of `bench_real naip`: two sessions rendered from the 2009 and 2015 orthophotos along one path,
mapped and matched in both orders and scored against the exact shared truth (the identity), with the negative
controls (opposite halves, a mirrored orthophoto) and the match drawn over the orthophoto. `evaluation_cases` is the
real-data hook of `bench_evaluate`."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np


def naip_sessions(naip: Path, work: Path, extra_args: list[str], map_args: list[str] | None = None,
                  tifs: list[Path] | None = None) -> tuple[list[tuple[Path, Path]], dict]:
    """Render both NAIP dates (or the given `tifs`) along one path (`synth-from-ortho`, extra_args passed on) and
    map them (`sosmatch map`, map_args passed on, e.g. ["--preset", "aerial"]); existing sessions and maps in
    `work` are reused. Returns [(session, mapped session)] in the order of `tifs` (default: file-name order, oldest
    first), and the timings."""
    from ..cli import main as cli

    tifs = sorted(naip.glob("*.tif")) if tifs is None else list(tifs)
    if len(tifs) != 2:
        raise SystemExit(f"expected two GeoTIFFs in {naip}")
    times = {}
    sessions = []
    for tif in tifs:
        name = tif.stem.rsplit("_", 1)[-1]
        sess, mapped = work / f"naip_{name}", work / f"naip_{name}_map"
        t0 = time.perf_counter()
        if not (sess / "session.json").exists():
            assert cli(["synth-from-ortho", str(tif), "--out", str(sess), "--max-tilt", "3", *extra_args]) == 0
        times[f"render_{name}_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        if not (mapped / "run.json").exists():
            assert cli(["map", "--poses", str(sess), "--out", str(mapped), "--no-progress", *(map_args or [])]) == 0
        times[f"map_{name}_s"] = time.perf_counter() - t0
        sessions.append((sess, mapped))
    return sessions, times


def half_orthophoto(tif: Path, side: str, out: Path) -> Path:
    """The west or east half (`side`) of `tif`, georeferenced, written once to `out`: a negative control of
    `naip_check`. Two halves share no ground, so a match between maps of opposite halves must accept nothing."""
    import rasterio
    from rasterio.windows import Window

    if not out.exists():
        with rasterio.open(tif) as src:
            half = src.width // 2
            win = Window(0, 0, half, src.height) if side == "west" else \
                Window(half, 0, src.width - half, src.height)
            profile = src.profile.copy()
            profile.update(width=win.width, height=win.height, transform=src.window_transform(win))
            data = src.read(window=win)
        _write_raster(out, data, profile)
    return out


def mirrored_orthophoto(tif: Path, out: Path) -> Path:
    """`tif` flipped east-west under the same georeference, written once to `out`: the full-size negative control
    of `naip_check` (same ponds, sizes and density as the real date, at mirrored places). A mirrored flat map is
    the original turned upside down, so that set is rejected only by the gravity gate (theta_alpha); what the
    control tests is that no upright chance set is accepted."""
    import rasterio

    if not out.exists():
        with rasterio.open(tif) as src:
            data, profile = src.read()[:, :, ::-1], src.profile
        _write_raster(out, data, profile)
    return out


def _write_raster(out: Path, data: np.ndarray, profile: dict) -> None:
    """Write a GeoTIFF atomically (a temporary sibling, then rename): a killed run leaves no half raster that the
    next run would take as done."""
    import rasterio

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.stem + ".tmp.tif")
    with rasterio.open(tmp, "w", **profile) as dst:
        dst.write(data)
    tmp.replace(out)


def evaluation_cases(data_root: Path, work: Path) -> list[dict]:
    """Real-data cases for `bench_evaluate --real`: NAIP 2009 vs 2015 rendered along one path (frames every 75 m)
    and mapped; the sessions carry exact poses, footprints and a flat terrain at z = 0, so the paper's evaluation
    (footprint IoU ground truth, PR curves against ORB/SIFT + RANSAC) runs unchanged."""
    naip = Path(data_root) / "naip"
    if not naip.is_dir():
        return []
    (a, map_a), (b, map_b) = naip_sessions(naip, Path(work), ["--frame-spacing", "75"])[0]
    return [{"case": "naip-2009-2015", "session_a": a, "session_b": b, "map_a": map_a, "map_b": map_b,
             "ground_height": 0.0}]


def _identity_error(transform: dict, centre: np.ndarray) -> tuple[float, float]:
    """How far a match.json transform (A_from_B) is from the identity: displacement of `centre` (m), angle (deg)."""
    from ...plugin.geometry import rotation_angle_deg
    from ...plugin.multisession import Sim3

    sim = Sim3.from_dict(transform)
    return float(np.linalg.norm(sim.apply(centre) - centre)), rotation_angle_deg(sim.rotation, np.eye(3))


def _score_match(map_a: Path, map_b: Path, match_dir: Path) -> dict:
    """Accepted count and, if a hypothesis was accepted, its error against the identity (see `naip_check`)."""
    import json

    from ...database.landmark_map import read_landmark_map

    a = read_landmark_map(map_a / "landmarks.sosmap")
    b = read_landmark_map(map_b / "landmarks.sosmap")
    from ...database.match_io import read_match

    result = json.loads((match_dir / "match.json").read_text())
    answer = read_match(match_dir / "match.json")  # what every consumer uses: the verified alignment
    out = {"landmarks": [len(a), len(b)], "window_pairs_solved": result.get("num_solved"),
           "accepted": result.get("num_accepted"), "match_s": result.get("seconds_total"),
           "search_s": result.get("search_seconds"), "search_mode": result.get("search_mode"),
           "answer": answer.source, "answer_accepted": bool(answer.accepted),
           "answer_support": len(answer.associations) if answer.accepted else 0,
           "runner_up_support": answer.runner_up_support}
    # the margin to theta_S: the largest upright (tilt <= theta_alpha) hypothesis that is wrong, i.e. off the
    # identity by more than the bar (15 m at B's landmark centroid or 2 degrees); every one is, for the controls
    centre = b.positions.mean(axis=0)
    max_tilt = result["params"]["association"]["max_gravity_angle_deg"]
    wrong = [0]
    for h in result["hypotheses"]:
        if h.get("transform") and h.get("tilt_deg") is not None and h["tilt_deg"] <= max_tilt:
            err_m, err_deg = _identity_error(h["transform"], centre)
            if err_m > 15.0 or err_deg > 2.0:
                wrong.append(h["size"])
    out["largest_wrong_upright_hypothesis"] = max(wrong)
    out["largest_right_hypothesis"] = max([h["size"] for h in result["hypotheses"] if h.get("transform")
                                           and h.get("tilt_deg") is not None and h["tilt_deg"] <= max_tilt
                                           and max(_identity_error(h["transform"], centre)[0] / 15.0,
                                                   _identity_error(h["transform"], centre)[1] / 2.0) <= 1.0],
                                          default=0)
    out["association"] = {k: result["params"]["association"].get(k) for k in
                          ("distance_tolerance_m", "affinity_sigma_m", "max_size_difference", "window_length",
                           "window_stride", "window_factor_a", "window_factor_b", "min_associations",
                           "derive_from_maps")}
    out["verified"] = _verified(match_dir, centre)
    best = result.get("consensus") or (result["hypotheses"][result["best"]] if result.get("best") is not None
                                       else None)
    if answer.accepted:
        out["answer_error_m"], out["answer_error_deg"] = _identity_error(answer.transform.to_dict(), centre)
    if best:
        out["transform_error_m"], out["transform_error_deg"] = _identity_error(best["transform"], centre)
        assoc = np.array(best["associations"]).reshape(-1, 2)
        d = np.linalg.norm(a.positions[assoc[:, 0], :2] - b.positions[assoc[:, 1], :2], axis=1)
        out["associations"] = len(assoc)
        out["associations_within_10m"] = int(np.sum(d < 10.0))
        out["association_distance_median_m"] = float(np.median(d)) if len(d) else float("nan")
    return out


def _verified(match_dir: Path, centre: np.ndarray) -> dict:
    """The match's answer as `sosmatch match` verified it on the full maps (match.json "verification", the one
    verification `batch` and `evaluate` read too): its support, the best rival's, whether it was accepted, its
    error to the identity."""
    from ...database.match_io import read_match, read_match_json
    from ...plugin.geometry import rotation_angle_deg

    ver = read_match_json(match_dir / "match.json").get("verification")
    if not ver:
        return {"support": 0, "runner_up_support": 0, "accepted": False}
    out = {"support": int(ver.get("support", 0)), "runner_up_support": int(ver.get("runner_up_support", 0)),
           "accepted": bool(ver.get("accepted"))}
    t = read_match(match_dir / "match.json").transform
    if t is not None:
        out.update(error_m=float(np.linalg.norm(t.apply(centre[None])[0] - centre)),
                   error_deg=float(rotation_angle_deg(t.rotation, np.eye(3))))
    return out


def draw_naip_match(tif: Path, map_a: Path, map_b: Path, match_dir: Path, out: Path, width: int = 934) -> None:
    """A figure: both maps' landmarks on the orthophoto `tif` (A red, B cyan, circles of the landmarks' metric
    size), the accepted answer's associations (`database.match_io.read_match`: the verified alignment's) as
    yellow lines from A's landmark to B's, B's landmarks moved by the accepted transform (the truth is the
    identity, so a line's length is the pair's disagreement)."""
    import cv2
    import rasterio

    from ...database.landmark_map import read_landmark_map
    from ...database.match_io import read_match

    with rasterio.open(tif) as src:
        rgb = np.moveaxis(src.read([1, 2, 3]), 0, -1)
        inverse, gsd = ~src.transform, abs(src.transform.a)
    img = np.ascontiguousarray(rgb[:, :, ::-1])
    scale = width / img.shape[1]
    img = cv2.resize(img, (width, int(round(img.shape[0] * scale))), interpolation=cv2.INTER_AREA)

    def pixels(xy: np.ndarray) -> np.ndarray:
        cols, rows = inverse * (xy[:, 0], xy[:, 1])
        return np.round(np.column_stack([cols, rows]) * scale).astype(int)

    a = read_landmark_map(map_a / "landmarks.sosmap")
    b = read_landmark_map(map_b / "landmarks.sosmap")
    answer = read_match(match_dir)  # the answer every consumer reads: the verified alignment where there is one
    accepted = answer.accepted and answer.transform is not None
    pb = answer.transform.apply(b.positions) if accepted else b.positions
    for pos, sizes, colour in ((a.positions, a.sizes, (0, 0, 255)), (pb, b.sizes, (255, 255, 0))):
        for (u, v), size in zip(pixels(pos), sizes):
            cv2.circle(img, (int(u), int(v)), max(2, int(round(size / gsd * scale))), colour, 1, cv2.LINE_AA)
    if accepted:
        assoc = answer.associations.reshape(-1, 2)
        for (ua, va), (ub, vb) in zip(pixels(a.positions[assoc[:, 0]]), pixels(pb[assoc[:, 1]])):
            cv2.line(img, (int(ua), int(va)), (int(ub), int(vb)), (0, 255, 255), 3, cv2.LINE_AA)
            cv2.circle(img, (int(ua), int(va)), 9, (0, 255, 255), 2, cv2.LINE_AA)
    labels = [f"A: {len(a)} landmarks (red); B: {len(b)} (cyan), moved by the accepted transform",
              f"{len(answer.associations) if accepted else 0} {answer.source} associations (yellow)"]
    cv2.rectangle(img, (0, 0), (600, 48), (0, 0, 0), -1)
    for row, label in enumerate(labels):
        cv2.putText(img, label, (8, 18 + 20 * row), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), img, [cv2.IMWRITE_JPEG_QUALITY, 85])


def naip_check(naip: Path, work: Path, extra_args: list[str], preset: str = "paper",
               map_args: list[str] | None = None, both_orders: bool = True, control: bool = True,
               match_sets: list[str] | None = None) -> dict:
    """Render both NAIP dates along one path, map both (`map_args`), match (parameters: `preset`); score against
    the identity ground truth. The transform is in world (UTM) coordinates, so its error is taken where the data
    is: the displacement of B's landmark centroid, and the rotation angle. `both_orders`: also match 2009 into
    2015. `control`: the negative control, maps of the west half of one date against the east half of the other
    (`half_orthophoto`; rendered and mapped alike), both ways round, and of 2009's two halves: they share no
    ground, so nothing may be accepted; and 2009 against the 2015 orthophoto mirrored (`mirrored_orthophoto`).
    Each match reports the largest upright (tilt <= theta_alpha) hypothesis: the margin to theta_S, and the
    match's window hypotheses verified on the full maps as `batch` and `evaluate` do (`_verified`): the verified
    alignment's support, its rival's, and its error. `preset` "none": the defaults; `match_sets`: `--set` of the
    match (e.g. association.derive_from_maps=true: tolerances from the maps' own noise, plugin.map_noise)."""
    from ..cli import main as cli

    sessions, times = naip_sessions(naip, work, extra_args, map_args)
    out: dict = {"preset": preset, **times}
    runs = [("2015_into_2009", sessions[0][1], sessions[1][1])]
    if both_orders:
        runs.append(("2009_into_2015", sessions[1][1], sessions[0][1]))
    if control:
        old, new = sorted(naip.glob("*.tif"))
        halves = {(t, side): half_orthophoto(t, side, work / "control" / f"{t.stem}{side}.tif")
                  for t in (old, new) for side in ("west", "east")}
        for a, b in (((old, "west"), (new, "east")), ((old, "east"), (new, "west")), ((old, "west"), (old, "east"))):
            ctrl, ctrl_times = naip_sessions(naip, work, extra_args, map_args, tifs=[halves[a], halves[b]])
            out.update({f"control_{k}": v for k, v in ctrl_times.items()})
            runs.append((f"control_{a[1]}{a[0].stem[-8:-4]}_{b[1]}{b[0].stem[-8:-4]}", ctrl[0][1], ctrl[1][1]))
        mirror = mirrored_orthophoto(new, work / "control" / f"{new.stem}mirrored.tif")
        ctrl, ctrl_times = naip_sessions(naip, work, extra_args, map_args, tifs=[old, mirror])
        out.update({f"control_{k}": v for k, v in ctrl_times.items() if "mirrored" in k})
        runs.append(("control_2009_mirrored2015", ctrl[0][1], ctrl[1][1]))
    for label, map_a, map_b in runs:
        tag = preset + "".join(f"_{kv.split('.')[-1]}" for kv in match_sets or [])
        match_dir = work / f"naip_match_{tag}_{label}"
        flags = ([] if preset == "none" else ["--preset", preset])
        flags += [x for kv in match_sets or [] for x in ("--set", kv)]
        assert cli(["match", str(map_a), str(map_b), "--out", str(match_dir), "--no-plot", *flags]) == 0
        out[label] = _score_match(map_a, map_b, match_dir)
    tag = preset + "".join(f"_{kv.split('.')[-1]}" for kv in match_sets or [])
    draw_naip_match(sorted(naip.glob("*.tif"))[0], sessions[0][1], sessions[1][1],
                    work / f"naip_match_{tag}_2015_into_2009", work / "naip_match.jpg")
    out["figure"] = str(work / "naip_match.jpg")
    return out
