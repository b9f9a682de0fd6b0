"""Images at one recorded position (nu49): a copy of an image (byte-identical, or the same pixels in another
format) is named and left out; a pose row repeating the previous frame's position while the camera moved (a GPS
updating slower than the camera) is named as a pose fault. Real synthetic flights (`sosmatch synth`)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from sosmatch.database.poses import read_poses_csv, write_poses_csv
from sosmatch.plugin.geometry import Poses
from sosmatch.tools.cli import main
from sosmatch.workflows.map.inputs import distinct_images, load_inputs


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("repeated") / "flight"
    assert main(["synth", "--out", str(out), "--frames", "12", "--width", "320", "--height", "240", "-q"]) == 0
    return out


def _folder(flight: Path, root: Path, png_copies: tuple[int, ...] = (), repeat: int | None = None,
            turn_deg: float = 0.0, rounding_m: float = 0.0) -> Path:
    """The flight's images and poses in `root`: PNG copies of some images beside them (their poses those of the
    originals), and optionally image `repeat` + 1 given image `repeat`'s position (its recorded attitude turned
    by `turn_deg` about the vertical). `rounding_m`: the copied positions differ from their originals' by this
    much along each axis (rounding of a CSV or a conversion)."""
    poses, epsg = read_poses_csv(flight / "poses.csv")
    (root / "images").mkdir(parents=True)
    for n in poses.names:
        (root / "images" / n).write_bytes((flight / "images" / n).read_bytes())
    names, rotations, centers = list(poses.names), list(poses.rotations), list(poses.centers.copy())
    for i in png_copies:
        png = Path(poses.names[i]).stem + ".png"
        cv2.imwrite(str(root / "images" / png), cv2.imread(str(flight / "images" / poses.names[i])))
        names.append(png)
        rotations.append(poses.rotations[i])
        centers.append(poses.centers[i] + rounding_m)
    if repeat is not None:
        centers[repeat + 1] = centers[repeat] + rounding_m
        t = np.radians(turn_deg)
        yaw = np.array([[np.cos(t), -np.sin(t), 0.0], [np.sin(t), np.cos(t), 0.0], [0.0, 0.0, 1.0]])
        rotations[repeat + 1] = rotations[repeat + 1] @ yaw.T  # camera-from-world after a turn about the vertical
    write_poses_csv(root / "poses.csv", Poses(names, np.array(rotations), np.array(centers)), epsg=epsg)
    return root


def test_a_copy_in_another_format_is_named_and_left_out_once(flight, tmp_path, caplog):
    """nu49: PNG copies (pixel-identical, other bytes) beside their JPEGs, with the same poses, were mapped without a
    word (only byte-identical copies were named): each made a pair without baseline for the pose check."""
    root = _folder(flight, tmp_path / "png", png_copies=(3, 7))
    inputs = load_inputs(root / "images", root / "poses.csv", flight / "cameras.txt")
    with caplog.at_level("WARNING"):
        kept, digests = distinct_images(inputs)
    names = sorted(p.name for p in kept.image_paths)
    assert names == sorted(read_poses_csv(flight / "poses.csv")[0].names) and len(digests) == len(names)
    said = [w for w in kept.warnings if "same view as another at the same recorded position" in w]
    assert len(said) == 1 and "frame_00003.jpg = frame_00003.png" in said[0] and said[0] in caplog.text
    # not told to remove them as copies: a hovering drone's next exposure shows the same view too (rev37)
    assert "remove the copies" not in said[0] and "hover" in said[0]
    assert not any("recorded position of another" in w or "copies of others" in w for w in kept.warnings)


def test_a_repeated_position_of_a_moving_camera_is_named(flight, tmp_path):
    """nu49: one pose row repeating the previous frame's position: the image whose pose is off was never named."""
    root = _folder(flight, tmp_path / "rep", repeat=5)
    inputs = load_inputs(root / "images", root / "poses.csv", flight / "cameras.txt")
    kept, _ = distinct_images(inputs)
    assert len(kept.image_paths) == len(inputs.image_paths)  # both kept: a pose fault, not a copy
    said = [w for w in kept.warnings if "recorded position of another" in w]
    names = inputs.poses.names
    assert len(said) == 1 and f"{names[6]} repeats {names[5]}'s" in said[0], kept.warnings
    assert not any("copies of others" in w for w in kept.warnings)


def test_a_turn_at_one_recorded_position_is_not_called_a_wrong_position(flight, tmp_path):
    """rev37: a drone turning in place at one recorded position (its attitude recorded, changed) was told one of the
    two positions is wrong; it is named as a turn, both kept."""
    root = _folder(flight, tmp_path / "turn", repeat=5, turn_deg=30.0)
    inputs = load_inputs(root / "images", root / "poses.csv", flight / "cameras.txt")
    kept, _ = distinct_images(inputs)
    assert len(kept.image_paths) == len(inputs.image_paths)
    names = inputs.poses.names
    said = [w for w in kept.warnings if "different recorded attitude" in w]
    assert len(said) == 1 and f"{names[6]} at {names[5]}'s, turned 30 deg" in said[0], kept.warnings
    assert not any("whose view differs" in w for w in kept.warnings)


def test_a_clean_flight_keeps_every_image_without_a_word(flight):
    inputs = load_inputs(flight / "images", flight / "poses.csv", flight / "cameras.txt")
    kept, digests = distinct_images(inputs)
    assert kept is inputs and len(digests) == len(inputs.image_paths) and kept.warnings == []


def test_positions_that_differ_by_rounding_are_one_position(flight, tmp_path):
    """Positions were one only when exactly equal: a PNG copy whose pose row differs from its original's by 1e-9 m
    (a CSV's or a conversion's rounding) was kept, and a row repeating the previous frame's position to within
    1e-9 m was not named. Within `geometry.SAME_POSITION` (1 um) they are one position."""
    root = _folder(flight, tmp_path / "png", png_copies=(3,), rounding_m=1e-9)
    inputs = load_inputs(root / "images", root / "poses.csv", flight / "cameras.txt")
    assert not np.array_equal(inputs.poses.centers[inputs.poses.names.index("frame_00003.png")],
                              inputs.poses.centers[inputs.poses.names.index("frame_00003.jpg")])  # read as written
    kept, _ = distinct_images(inputs)
    assert "frame_00003.png" not in [p.name for p in kept.image_paths]
    root = _folder(flight, tmp_path / "rep", repeat=5, rounding_m=1e-9)
    inputs = load_inputs(root / "images", root / "poses.csv", flight / "cameras.txt")
    kept, _ = distinct_images(inputs)
    names = inputs.poses.names
    assert any(f"{names[6]} repeats {names[5]}'s" in w for w in kept.warnings), kept.warnings


def test_one_position_is_rounding_not_the_receivers_jitter():
    """`position_groups` at UTM magnitudes: 1e-9 m apart (about one ulp there) is one position; 0.1 mm apart (an
    RTK hover's jitter) are two, as are a slow flight's frames 1 m apart."""
    from sosmatch.plugin.geometry import SAME_POSITION, position_groups

    base = np.array([523_456.789, 4_712_345.678, 312.5])
    c = np.array([base, base + [1e-9, -1e-9, 0.0], base + [1e-4, 0.0, 0.0], base + [1.0, 0.0, 0.0],
                  base + [0.0, 0.0, 2e-9], base + [1.0, 0.0, 3e-9]])
    assert position_groups(c) == [[0, 1, 4], [2], [3, 5]]
    # a group is the positions within the tolerance of its first: no chain of near ones grows it
    chain = base + np.outer(np.arange(4), [0.6 * SAME_POSITION, 0.0, 0.0])
    assert position_groups(chain) == [[0, 1], [2, 3]]
    assert position_groups(np.array([[np.nan, 0.0], [np.nan, 0.0]])) == [[0], [1]]
