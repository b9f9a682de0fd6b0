"""The poses against the images (`workflows.pose_check`): figures and verdicts on good and deliberately wrong poses.

Sessions are bench_plausibility's (`sosmatch synth`, cached in WORK/sessions; 100 frames, 640x480, world 7 summer
lawnmower at 100 m unless stated). Good poses: exact and EKF over worlds, seasons, heights, flight paths, a lens
with distortion (true model, and ignored), a 16:9 crop; `--real NAME IMAGES POSES CAMERA` adds real flights
(e.g. Seneca on refined or SfM poses). Wrong poses: the tags of `synth --geotags` read as they are (no SfM), and
faults applied to the exact poses: a linear 50 m height drift, one pass turned 180 deg, 1.5 m / 3 m and 5 m GPS
noise, 2 deg attitude noise, centres on a 40 deg plane, a block rotated 30 deg (rigid: the images agree, only
gravity can tell; `plugin.map_quality` refuses it), and three heading conventions (mirrored, +90 deg, north-up
compass read as east-up). Low flights: 50 frames of 480x360 at 40 m, four over three worlds, EKF poses (good), their
exact poses with a 20 m drift and their EKF poses on a 40 deg plane (wrong). `--real-bad` adds real flights
known to be wrong (Seneca's raw telemetry).

    .venv/bin/python -m sosmatch.tools.benchmarks.bench_pose_check --work DIR [--only NAME ...]
        [--real NAME IMAGES POSES CAMERA] [--real-bad NAME IMAGES POSES CAMERA] [--preset survey]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ...plugin.errors import InputError
from .bench_plausibility import CASES, W7, Case, _session
from .machine import machine_summary


def _rot(axis: str, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    if axis == "x":
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def faulty(poses: Any, kind: str, seed: int = 0) -> Any:
    """`poses` with one deliberate fault (module doc)."""
    from ...plugin.geometry import Poses
    from ...plugin.pass_heights import flight_passes

    rng = np.random.default_rng(seed)
    r, c = poses.rotations.copy(), poses.centers.copy()
    n, m = len(poses), poses.centers.mean(axis=0)
    if kind == "drift 50 m":
        c[:, 2] += 50.0 * np.arange(n) / (n - 1)
    elif kind == "drift 20 m":
        c[:, 2] += 20.0 * np.arange(n) / (n - 1)
    elif kind == "pass 2 yaw 180":
        sel = flight_passes(c) == 2
        r[sel] = _rot("z", 180.0) @ r[sel]
    elif kind == "GPS 1.5 m / 3 m":
        c += np.c_[rng.normal(0, 1.5, (n, 2)), rng.normal(0, 3.0, n)]
    elif kind == "GPS 5 m":
        c += rng.normal(0, 5.0, (n, 3))
    elif kind == "attitude noise 2 deg":
        from scipy.spatial.transform import Rotation

        r = Rotation.from_rotvec(rng.normal(0, np.radians(2.0), (n, 3))).as_matrix() @ r
    elif kind == "centres on a 40 deg plane":
        c = (c - m) @ _rot("x", 40.0).T + m
    elif kind == "block rotated 30 deg":
        t = _rot("x", 30.0)
        c, r = (c - m) @ t.T + m, t @ r
    elif kind.startswith("heading "):
        top = -r[:, :, 1]  # the image's up direction on the ground
        h = np.arctan2(top[:, 1], top[:, 0])
        new = {"heading mirrored": -h, "heading +90 deg": h + np.pi / 2, "heading north-up as east-up": np.pi / 2 - h}
        r = np.stack([_rot("z", np.degrees(a - b)) @ ri for a, b, ri in zip(new[kind], h, r)])
    else:
        raise ValueError(kind)
    return Poses(poses.names, r, c)


FAULTS = ["drift 50 m", "pass 2 yaw 180", "GPS 1.5 m / 3 m", "GPS 5 m", "attitude noise 2 deg",
          "centres on a 40 deg plane", "block rotated 30 deg", "heading mirrored", "heading +90 deg",
          "heading north-up as east-up"]


def _cases(work: Path, frames: int) -> list[tuple[str, bool, Any]]:
    """(name, good, inputs loader) for every synthetic case."""
    from ...workflows import map as map_workflow
    from ...workflows.poses_from_exif import map_inputs_from_images

    out: list[tuple[str, bool, Any]] = []
    for case in CASES:  # bench_plausibility's sessions: good exact / EKF poses and the EXIF/XMP tag faults
        if case.poses in ("exact", "ekf"):
            out.append((f"{case.name} ({case.poses})", True,
                        lambda c=case: map_workflow.load_inputs(None, _session(work, c, frames), ekf=c.poses == "ekf")))
        elif case.poses == "exif":
            out.append((case.name, False, lambda c=case: map_inputs_from_images(_session(work, c, frames) / "images")))
    lens = Case("lens k1=-0.1", True, {**W7, "lens_k1": -0.1})

    def ignored() -> Any:
        inputs = map_workflow.load_inputs(None, _session(work, lens, frames))
        return replace(inputs, camera=inputs.camera.pinhole())

    out.append(("lens k1=-0.1 ignored (PINHOLE camera)", False, ignored))
    exact = Case("exact", True, W7)
    for kind in FAULTS:
        def load(kind: str = kind) -> Any:
            inputs = map_workflow.load_inputs(None, _session(work, exact, frames))
            return replace(inputs, poses=faulty(inputs.poses, kind))

        out.append((f"exact poses, {kind}", False, load))
    # low flights of small images (the seventh new-user sweep): few pairs match and the poses' random errors are
    # large against the baselines, where an unconstrained systematic fit once refused correct EKF poses
    for world, session in LOW_FLIGHTS:
        low = Case(f"world {world} flight {session} at 40 m", True, {"world_seed": world, "session_seed": session,
                                                             "altitude_m": 40.0, "width": 480, "height": 360})
        out.append((f"{low.name} (ekf)", True, lambda c=low: map_workflow.load_inputs(
            None, _session(work, c, LOW_FRAMES), ekf=True)))
        for kind, ekf in (("drift 20 m", False), ("centres on a 40 deg plane", True)):
            def load_low(kind: str = kind, ekf: bool = ekf, c: Case = low) -> Any:
                inputs = map_workflow.load_inputs(None, _session(work, c, LOW_FRAMES), ekf=ekf)
                return replace(inputs, poses=faulty(inputs.poses, kind))

            out.append((f"{low.name}, {'ekf' if ekf else 'exact'} poses, {kind}", False, load_low))
    return out


LOW_FLIGHTS = [(19, 31), (5, 31), (5, 32), (11, 31)]  # (world, session) seeds
LOW_FRAMES = 50


def run_case(name: str, good: bool, inputs: Any, params: Any) -> dict[str, Any]:
    from ...workflows import pose_check

    t = time.process_time()
    result, verdict = pose_check.check(inputs.image_paths, inputs.poses, inputs.camera, params)
    s = result.systematic
    return {"case": name, "good": good, "cpu_s": round(time.process_time() - t, 1),
            "pairs": f"{result.pairs_checked}/{result.pairs_tried}", "flying_height_m": result.flying_height_m,
            "gate_px": result.gate_px, "epipolar_p50_px": result.epipolar_p50_px,
            "epipolar_fit_p50_px": result.epipolar_fit_p50_px, "reversed_pairs": result.reversed_pairs,
            "drift": f"{s.height_drift_m:+.1f} +- {s.height_drift_sigma_m:.1f}",
            "tilt": f"{s.height_tilt_deg:.1f} +- {s.height_tilt_sigma_deg:.1f}",
            "attitude": f"{s.attitude_bias_deg:.2f} +- {s.attitude_bias_sigma_deg:.2f}",
            "explained": f"{s.explained_f:.1f} ({s.explained_p:.1g}), {100 * s.explained_share:.0f} %",
            "refusals": verdict.refusals, "warnings": verdict.warnings}


def refused_on_reading(name: str, good: bool, error: str) -> dict[str, Any]:
    """A row for a case whose poses were refused when read, before any check ran."""
    return {"case": name, "good": good, "cpu_s": 0.0, "pairs": "-", "flying_height_m": float("nan"),
            "gate_px": float("nan"), "epipolar_p50_px": float("nan"), "epipolar_fit_p50_px": float("nan"),
            "reversed_pairs": "-", "drift": "-", "tilt": "-", "attitude": "-", "explained": "-",
            "refusals": [f"refused when read: {error.split(': ', 1)[-1]}"], "warnings": []}


def main(argv: list[str] | None = None) -> int:
    from ...database.config_io import load_params
    from ...workflows import map as map_workflow

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, required=True, help="sessions go here (shared with bench_plausibility)")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--only", nargs="*", help="case names (substrings) to run")
    ap.add_argument("--real", nargs=4, action="append", default=[], metavar=("NAME", "IMAGES", "POSES", "CAMERA"))
    ap.add_argument("--real-bad", nargs=4, action="append", default=[], metavar=("NAME", "IMAGES", "POSES", "CAMERA"))
    ap.add_argument("--preset", default="survey", help="preset of the real flights (their tracker's gate)")
    args = ap.parse_args(argv)
    print(machine_summary())
    cases = _cases(args.work, args.frames)
    for good, reals in ((True, args.real), (False, args.real_bad)):
        for name, images, poses, camera in reals:
            cases.append((name, good, lambda i=images, p=poses, c=camera: map_workflow.load_inputs(
                Path(i), Path(p), Path(c)), args.preset))
    rows = []
    for case in cases:
        name, good, load = case[:3]
        if args.only and not any(o in name for o in args.only):
            continue
        params = load_params(preset=case[3] if len(case) > 3 else ("survey" if "survey" in name else "paper"))
        try:
            inputs = load()
        except InputError as exc:  # refused before the check (e.g. `poses-from-exif` cannot solve the attitudes)
            rows.append(refused_on_reading(name, good, str(exc)))
        else:
            rows.append(run_case(name, good, inputs, params))
        r = rows[-1]
        print(f"  {name}: {'refused' if r['refusals'] else 'kept'} ({r['cpu_s']} CPU-s)", flush=True)
    print("| poses | should be | verdict | pairs | H m | epipolar p50 px (gate) | after fit | reversed pairs | "
          "height drift m | height tilt deg | attitude deg | fit F (p), share | reason / warning |")
    print("|---|---|---|---|---:|---|---:|---:|---|---|---|---|---|")
    for r in rows:
        reason = "; ".join(x.removeprefix("poses vs images: ") for x in (r["refusals"] or r["warnings"]))[:110]
        print(f"| {r['case']} | {'kept' if r['good'] else 'refused'} | {'refused' if r['refusals'] else 'kept'} | "
              f"{r['pairs']} | {r['flying_height_m']:.0f} | {r['epipolar_p50_px']:.2f} ({r['gate_px']:.0f}) | "
              f"{r['epipolar_fit_p50_px']:.2f} | {r['reversed_pairs']} | {r['drift']} | {r['tilt']} | "
              f"{r['attitude']} | {r['explained']} | {reason} |")
    good = [r for r in rows if r["good"]]
    bad = [r for r in rows if not r["good"]]
    print(f"false refusals {sum(bool(r['refusals']) for r in good)} of {len(good)}, true refusals "
          f"{sum(bool(r['refusals']) for r in bad)} of {len(bad)}; CPU per check "
          f"{min(r['cpu_s'] for r in rows):.1f}-{max(r['cpu_s'] for r in rows):.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
