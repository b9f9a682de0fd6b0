"""`sosmatch demo`: the end-to-end demonstration, as a list of named steps.

    from sosmatch.workflows.demo import run_demo
    run_demo("demo_out")

Each step names the files it produces; a step whose outputs all exist is skipped, so an interrupted demo
resumes where it stopped (every output is written atomically). Later stages append their steps in
`demo_steps` (map, match, evaluate) using the paths in `DemoContext`.

Steps so far:
1. synth-summer: a 80-frame lawnmower survey of world 7 in summer (sun from the south-east).
2. synth-winter: the same path in winter (low sun from the south-south-west, other camera noise and objects
   changed, session seed 2).
3. contact-sheet: frames of both sessions side by side (contact_sheet.png).
4. map-summer, map-winter: `sosmatch map` of both sessions (true poses) into maps/summer, maps/winter; each
   prints its one-line summary.
5. match: `sosmatch match` of the two maps into match/ (match.json, associations.csv, match.png).
6. evaluate: footprint-IoU ground truth, our precision-recall against ORB+RANSAC and SIFT+RANSAC, the table
   and plots in evaluation/.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..database.atomic import write_bytes_atomic
from ..plugin.errors import InputError
from ..plugin.map_verdict import landmark_views
from ..plugin.params import Params
from ..tools.synth.config import SynthConfig

log = logging.getLogger(__name__)

DEMO_FRAMES = 80
DEMO_WORLD_SEED = 7


@dataclass
class DemoContext:
    """Paths and settings shared by the demo steps."""

    out: Path
    frames: int = DEMO_FRAMES
    overwrite: bool = False  # the steps replace their earlier outputs (--overwrite, or the demo's settings changed)
    summer: SynthConfig = field(init=False)
    winter: SynthConfig = field(init=False)

    def __post_init__(self) -> None:
        self.out = Path(self.out)
        common = dict(world_seed=DEMO_WORLD_SEED, frames=self.frames, flight="lawnmower")
        self.summer = SynthConfig(season="summer", session_seed=1, sun_azimuth_deg=135.0, **common)
        self.winter = SynthConfig(season="winter", session_seed=2, sun_azimuth_deg=200.0, **common)

    @property
    def summer_dir(self) -> Path:
        return self.out / "sessions" / "summer"

    @property
    def winter_dir(self) -> Path:
        return self.out / "sessions" / "winter"

    @property
    def contact_sheet(self) -> Path:
        return self.out / "contact_sheet.png"


@dataclass
class DemoStep:
    name: str
    outputs: list[Path]  # the step is skipped when all of these exist
    run: Callable[[DemoContext], object]


def _synth(which: str) -> Callable[[DemoContext], object]:
    def step(ctx: DemoContext) -> object:
        from .synth import run

        return run(getattr(ctx, f"{which}_dir"), getattr(ctx, which), progress=True, overwrite=ctx.overwrite)

    return step


def contact_sheet(session_dirs: list[Path], titles: list[str], out: Path, rows: int = 4,
                  scale: float = 0.5) -> Path:
    """A PNG of `rows` frames (evenly spaced through the flight) of each session side by side, labelled."""
    import cv2

    from ..database.synth_session import load_synth_session

    sessions = [load_synth_session(d) for d in session_dirs]
    n = min(len(s.poses) for s in sessions)
    picks = np.linspace(0, n - 1, rows + 2).round().astype(int)[1:-1]
    tiles = []
    for i in picks:
        row = []
        for s in sessions:
            img = cv2.imread(str(s.image_path(s.poses.names[i])), cv2.IMREAD_COLOR)
            img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
            cv2.putText(img, s.poses.names[i], (6, img.shape[0] - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                        (255, 255, 255), 1, cv2.LINE_AA)
            row.append(img)
            row.append(np.full((img.shape[0], 4, 3), 255, np.uint8))
        tiles.append(np.hstack(row[:-1]))
        tiles.append(np.full((4, tiles[-1].shape[1], 3), 255, np.uint8))
    body = np.vstack(tiles[:-1])
    header = np.full((28, body.shape[1], 3), 255, np.uint8)
    tile_w = (body.shape[1] - 4 * (len(sessions) - 1)) // len(sessions)
    for k, title in enumerate(titles):
        cv2.putText(header, title, (k * (tile_w + 4) + 6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1,
                    cv2.LINE_AA)
    sheet = np.vstack([header, body])
    ok, buf = cv2.imencode(".png", sheet, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:  # pragma: no cover
        raise RuntimeError("PNG encoding failed")
    write_bytes_atomic(out, buf.tobytes())
    return out


def _sheet(ctx: DemoContext) -> object:
    sa, ea = ctx.summer.sun()
    wa, we = ctx.winter.sun()
    return contact_sheet([ctx.summer_dir, ctx.winter_dir],
                         [f"summer (sun az {sa:.0f}, el {ea:.0f})", f"winter (sun az {wa:.0f}, el {we:.0f})"],
                         ctx.contact_sheet)


def map_dir(ctx: DemoContext, which: str) -> Path:
    """Mapped session directory of the demo's `which` ("summer" / "winter") session."""
    return ctx.out / "maps" / which


def _map(which: str) -> Callable[[DemoContext], object]:
    def step(ctx: DemoContext) -> object:
        from . import map as map_workflow

        inputs = map_workflow.load_inputs(None, getattr(ctx, f"{which}_dir"))
        summary = map_workflow.run(Params(), inputs, map_dir(ctx, which), overwrite=ctx.overwrite)
        print(f"map {which}: {summary.line()}")
        return summary

    return step


def _match(ctx: DemoContext) -> object:
    from . import match as match_workflow

    result = match_workflow.run(Params(), map_dir(ctx, "summer"), map_dir(ctx, "winter"), ctx.out / "match",
                                overwrite=ctx.overwrite)
    print(f"match summer vs winter: {result.summary()}  (alignment plot: {ctx.out / 'match' / 'match.png'})")
    return result


def _evaluate(ctx: DemoContext) -> object:
    from .evaluate import demo_step

    return demo_step(ctx.summer_dir, ctx.winter_dir, map_dir(ctx, "summer"), map_dir(ctx, "winter"),
                     ctx.out / "evaluation", overwrite=ctx.overwrite)


def demo_steps(ctx: DemoContext) -> list[DemoStep]:
    """The demo, in order. Later stages append their steps here."""
    return [
        DemoStep("synth-summer", [ctx.summer_dir / "session.json"], _synth("summer")),
        DemoStep("synth-winter", [ctx.winter_dir / "session.json"], _synth("winter")),
        DemoStep("contact-sheet", [ctx.contact_sheet], _sheet),
        DemoStep("map-summer", [map_dir(ctx, "summer") / "run.json"], _map("summer")),
        DemoStep("map-winter", [map_dir(ctx, "winter") / "run.json"], _map("winter")),
        DemoStep("match", [ctx.out / "match" / "match.json"], _match),
        DemoStep("evaluate", [ctx.out / "evaluation" / "evaluation.json"], _evaluate),  # keep last: the table
    ]


def fewest_frames(config: SynthConfig, params: Params) -> int:
    """The fewest frames of the demo's flight that `map` makes a map of: a landmark needs more than theta_n
    observations, one per keyframe, so theta_n + 1 keyframes on the first line must see its object. Keyframes lie
    `keyframes.interval_m` of travel apart (every frame when the frames lie further apart), and theta_n is the
    configured one as `map` lowers it for the flight's views per pass (`params.for_flight`, from the image's
    extent along the track over the motion per keyframe; the synthetic camera's image top points along it)."""
    from ..plugin.motion import views_per_pass
    from ..plugin.params import for_flight

    per_keyframe = max(1, math.ceil(params.keyframes.interval_m / config.spacing_m))
    camera = config.camera()
    motion_px = per_keyframe * config.spacing_m * camera.fx / config.altitude_m
    views = views_per_pass(np.array([motion_px]), np.array([[0.0, -1.0]]), camera.width, camera.height)
    theta_n = for_flight(params, views).triangulation.min_observations
    return theta_n * per_keyframe + 1


def run_demo(out: str | Path, frames: int = DEMO_FRAMES, overwrite: bool = False,
             force: bool = False) -> list[tuple[str, str, float]]:
    """Run every demo step into `out`; returns (step, "done" | "skipped", seconds) per step.

    `out` is taken through `sosmatch.database.outputs`; a demo made with another frame count is redone only
    with `overwrite` (which also re-runs every step; `force` is its earlier name)."""
    force = overwrite or force
    from ..database.output_markers import fingerprint
    from ..database.outputs import open_output_dir

    # before rendering: a flight too short for any landmark failed in map, after both sessions were rendered (nu45)
    configs = DemoContext(Path(out), frames)
    needed = max(fewest_frames(c, Params()) for c in (configs.summer, configs.winter))
    if frames < needed:
        raise InputError(f"--frames {frames} is too few to map: {landmark_views()}, on the flight's first line; "
                         f"give at least {needed} frames")
    identity = fingerprint({"frames": frames})
    with open_output_dir(out, "demo", identity, overwrite=force, legacy_record="sessions/summer/session.json") as taken:
        redo = force or (taken.previous.state != "new" and taken.previous.identity != identity)
        ctx = DemoContext(taken.path, frames, overwrite=redo)
        report = []
        for step in demo_steps(ctx):
            if not redo and step.outputs and all(p.exists() for p in step.outputs):
                log.info("demo step %s: outputs exist, skipped", step.name)
                report.append((step.name, "skipped", 0.0))
                continue
            t0 = time.perf_counter()
            log.info("demo step %s ...", step.name)
            step.run(ctx)
            report.append((step.name, "done", time.perf_counter() - t0))
        taken.finish()
    return report
