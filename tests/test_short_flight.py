"""A flight too short for any landmark (nu49): `map` of 5 frames refused with "the map has no landmarks" and no
cause, after a pose-check warning that blamed texture or poses for 4 of 4 pairs that all matched."""

from __future__ import annotations

from sosmatch.tools.cli import main


def test_a_flight_of_fewer_keyframes_than_a_landmark_needs_says_so(tmp_path, cli_error, caplog):
    session = tmp_path / "s5"
    assert main(["synth", "--out", str(session), "--frames", "5", "--width", "320", "--height", "240", "-q"]) == 0
    with caplog.at_level("WARNING"):
        err = cli_error("map", "--poses", session, "--ekf", "--out", tmp_path / "m5", "--no-progress", "-q")
    assert "the map has no landmarks: a landmark needs more than theta_n = 5 views, one per keyframe, and the flight " \
           "has 5 keyframes" in err
    said = [r.getMessage() for r in caplog.records if "poses vs images" in r.getMessage()]
    assert said and all("all matched" in w and "texture" not in w for w in said), said
