"""Image names that hold spaces (`DJI 00000.jpg`), commas or quotes: landmarks.csv keeps them whole, its readers
count a landmark's support from num_observations, and `map --text` and structure from motion refuse names that
COLMAP's text files (images.txt, pairs.txt) cannot hold (rev35)."""

import shutil

import numpy as np
import pytest

from sosmatch.database.landmark_map import LandmarkMap
from sosmatch.database.session_io import (
    LANDMARK_CSV_COLUMNS,
    format_landmarks_csv,
    read_landmark_table,
    read_session_observations,
    write_landmarks_csv,
)
from sosmatch.plugin.errors import InputError

AWKWARD = [["DJI 00000.jpg", "DJI 00001.jpg"], ["a,b.jpg", 'say "x".jpg', "tab\there.jpg", "ß 5.jpg"], []]


def _table_text(names):
    lmap = LandmarkMap(np.arange(9.0).reshape(3, 3), np.array([1.0, 2.0, np.nan], np.float32))
    return lmap, format_landmarks_csv(lmap, np.array([4, 7, -1]), np.array([len(n) for n in names]), names)


def test_landmarks_csv_keeps_any_image_name_whole(tmp_path):
    """With names joined by spaces, 8 observations of `DJI 00000.jpg` ... read back as 16 names 'DJI',
    '00000.jpg', ...: the support `changes` uses doubled and the evaluation looked up wrong names."""
    lmap, text = _table_text(AWKWARD)
    path = tmp_path / "landmarks.csv"
    write_landmarks_csv(path, lmap, np.array([4, 7, -1]), np.array([2, 4, 0]), AWKWARD)
    assert path.read_text(encoding="utf-8") == text
    assert text.splitlines()[0] == ",".join(LANDMARK_CSV_COLUMNS)
    table = read_landmark_table(path)
    assert table.image_names == AWKWARD and table.names_problem is None
    assert table.support.tolist() == [2, 4, 0] and table.point3d_ids.tolist() == [4, 7, -1]
    with pytest.raises(ValueError):  # the writer refuses what the reader would (an empty name)
        format_landmarks_csv(lmap, np.array([4, 7, -1]), np.array([1, 0, 0]), [[""], [], []])


@pytest.mark.parametrize("field", ['"not json"', '"[""a.jpg"", 3]"', '"[""a.jpg"""', "a.jpg"])
def test_a_names_field_that_is_no_list_of_names_is_one_line_naming_file_and_line(tmp_path, field):
    path = tmp_path / "landmarks.csv"
    path.write_text(",".join(LANDMARK_CSV_COLUMNS) + f"\n0,1,1,2,3,0.5,1,{field}\n")
    with pytest.raises(InputError, match="malformed landmark row") as err:
        read_landmark_table(path)
    assert str(err.value).startswith(f"{path}:2: ") and "\n" not in str(err.value)


def test_an_earlier_sosmatchs_table_still_reads_and_says_when_its_names_were_cut(tmp_path):
    """Tables written before image_names_json (`image_names`, joined by spaces) read as before; when a name held
    a space the words outnumber the observations: the counts stand, the names are refused where they are used."""
    path = tmp_path / "landmarks.csv"
    head = "index,point3d_id,x,y,z,size_m,num_observations,image_names\n"
    path.write_text(head + "0,5,4,5,6,1.5,2,a.jpg b.jpg\n1,6,1,2,3,,1,c.jpg\n")
    table = read_landmark_table(path)
    assert table.image_names == [["a.jpg", "b.jpg"], ["c.jpg"]] and table.names_problem is None
    assert table.names_or_raise(path) == table.image_names
    path.write_text(head + "0,5,4,5,6,1.5,2,DJI 00000.jpg DJI 00001.jpg\n1,6,1,2,3,,1,DJI 00002.jpg\n")
    table = read_landmark_table(path)
    assert table.support.tolist() == [2, 1]
    with pytest.raises(InputError, match=r"line 2: 4 names for 2 observations") as err:
        table.names_or_raise(path)
    assert str(err.value).startswith(f"{path}: ")
    # an older merge wrote a fused landmark's images once each but counted every observation: fewer names than
    # observations is no cut name (splitting at spaces only adds names)
    path.write_text(head + "0,5,4,5,6,1.5,3,a.jpg b.jpg\n")
    table = read_landmark_table(path)
    assert table.names_problem is None and table.names_or_raise(path) == [["a.jpg", "b.jpg"]]
    assert table.support.tolist() == [3]
    # without num_observations (older still): the names are all there is to count
    path.write_text("index,x,y,z,size_m,image_names\n0,1,2,3,1,a.jpg b.jpg c.jpg\n")
    assert read_landmark_table(path).support.tolist() == [3]


def test_changes_counts_support_from_the_observations_not_the_names(toy_sessions, tmp_path):
    """read_session_observations (what `changes` reads): a session whose earlier landmarks.csv held names with
    spaces had every landmark's support doubled."""
    session = tmp_path / "S"
    shutil.copytree(toy_sessions.a.path, session)
    table = read_landmark_table(session / "landmarks.csv")
    lines = ["index,point3d_id,x,y,z,size_m,num_observations,image_names"]
    for i, names in enumerate(table.image_names):
        x, y, z = (float(v) for v in table.positions[i])
        lines.append(f"{i},{table.point3d_ids[i]},{x!r},{y!r},{z!r},{float(table.sizes[i])!r},{len(names)},"
                     + " ".join(f"DJI {n}" for n in names))
    (session / "landmarks.csv").write_text("\n".join(lines) + "\n")
    support = read_session_observations(session, with_segments=False).support
    assert support.tolist() == [len(n) for n in table.image_names]


def _spaced_flight(root):
    """A 3-frame disc flight whose images are named `DJI 0000k.jpg`."""
    from sosmatch.database.poses import read_poses_csv, write_poses_csv
    from sosmatch.plugin.geometry import Camera, Poses
    from sosmatch.tools.toy_sessions import render_disc_flight

    render_disc_flight(root, Camera(160, 120, 120.0, 120.0, 80.0, 60.0), frames=3)
    poses = read_poses_csv(root / "poses.csv")[0]
    names = [f"DJI {k:05d}.jpg" for k in range(len(poses.names))]
    for old, new in zip(poses.names, names):
        (root / "images" / old).rename(root / "images" / new)
    write_poses_csv(root / "poses.csv", Poses(names, poses.rotations, poses.centers))
    return root


def test_map_text_refuses_image_names_with_white_space_before_any_work(tmp_path, cli_error):
    """COLMAP's images.txt ends a name at its first blank: `map --text` reported success and pycolmap read the
    model back as 40 images all named 'DJI' (then `changes`: "image 'DJI' of the model is not in the database").
    Refused up front now, naming the first such image; nothing is written."""
    root = _spaced_flight(tmp_path / "f")
    first = root / "images" / "DJI 00000.jpg"
    err = cli_error("map", "--images", root / "images", "--poses", root / "poses.csv", "--camera",
                    root / "cameras.txt", "--out", tmp_path / "M", "--text")
    assert err.startswith(f"sosmatch map: error: {first}: image name 'DJI 00000.jpg' holds white space")
    assert "text model" in err and "binary" in err and not (tmp_path / "M").exists()
    # poses made from the images (structure from motion): refused before they are made
    err = cli_error("map", "--images", root / "images", "--out", tmp_path / "M", "--text")
    assert f"{first}: image name 'DJI 00000.jpg' holds white space" in err and not (tmp_path / "M").exists()


def test_structure_from_motion_refuses_image_names_with_white_space_before_any_work(tmp_path, cli_error):
    """COLMAP's pair list (pairs.txt) ends a name at its first blank: after the whole feature extraction COLMAP
    matched no pair ("Image DJI does not exist" in its log). `poses` and `map` without poses refuse them up front."""
    root = _spaced_flight(tmp_path / "f")
    first = root / "images" / "DJI 00000.jpg"
    for argv in (("poses", root / "images", "--out", tmp_path / "P"), ("map", "--images", root / "images", "--out",
                                                                       tmp_path / "P")):
        err = cli_error(*argv)
        assert f"{first}: image name 'DJI 00000.jpg' holds white space, which COLMAP's list of image pairs" in err
        assert not (tmp_path / "P").exists()


def test_the_text_model_writer_refuses_names_it_cannot_hold(tmp_path):
    pycolmap = pytest.importorskip("pycolmap")
    from sosmatch.database.colmap_model import write_model

    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=160, height=120,
                                                    params=[100.0, 100.0, 80.0, 60.0], camera_id=1))
    rec.add_image_with_trivial_frame(pycolmap.Image(name="DJI 00000.jpg", keypoints=np.zeros((0, 2)), camera_id=1,
                                                    image_id=1), pycolmap.Rigid3d())
    with pytest.raises(ValueError, match="white space"):
        write_model(rec, tmp_path / "sparse", text=True)
    assert not (tmp_path / "sparse").exists()
    write_model(rec, tmp_path / "sparse")  # the binary model keeps the name
    assert [im.name for im in pycolmap.Reconstruction(str(tmp_path / "sparse")).images.values()] == ["DJI 00000.jpg"]
