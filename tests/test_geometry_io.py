"""Shared geometry and the pose / camera files."""

import numpy as np
import pytest

from sosmatch.database.cameras import read_cameras_txt, write_cameras_txt
from sosmatch.database.poses import read_poses_csv, write_poses_csv
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.geometry import Camera, Poses, project, quat_to_rotmat, rotmat_to_quat


def _random_poses(n=20, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return Poses([f"img{i}.jpg" for i in range(n)], quat_to_rotmat(q), rng.uniform(-100, 100, (n, 3)))


def test_quaternion_round_trip():
    poses = _random_poses()
    back = quat_to_rotmat(rotmat_to_quat(poses.rotations))
    assert np.allclose(back, poses.rotations, atol=1e-12)
    assert np.allclose(np.einsum("nij,nkj->nik", back, back), np.eye(3), atol=1e-12)


def test_projection_of_point_on_axis_hits_principal_point():
    cam = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)
    r_wc = np.diag([1.0, -1.0, -1.0])  # nadir: camera z points down
    uv, depth = project(cam, r_wc, np.array([0.0, 0.0, 100.0]), np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]]))
    assert np.allclose(uv[0], [320, 240]) and np.allclose(depth, 100)
    assert np.isclose(uv[1, 0], 320 + 50)


def test_pose_csv_round_trip_both_conventions(tmp_path):
    poses = _random_poses()
    path = tmp_path / "poses.csv"
    write_poses_csv(path, poses, epsg=32617)
    back, epsg = read_poses_csv(path)
    assert epsg == 32617 and back.names == poses.names
    assert np.allclose(back.centers, poses.centers) and np.allclose(back.rotations, poses.rotations)
    inverted, _ = read_poses_csv(path, convention="camera_from_world")
    assert not np.allclose(inverted.centers, poses.centers)


@pytest.mark.parametrize(
    "row, fragment",
    [
        ("a.jpg,1,2,nan,1,0,0,0", "NaN"),
        ("a.jpg,1,2,3,1,1,0,0", "unit"),
        ("a.jpg,1,2,3,1,0,0", "columns"),
        ("a.jpg,1,x,3,1,0,0,0", "non-numeric"),
    ],
)
def test_bad_pose_rows_name_file_and_line(tmp_path, row, fragment):
    path = tmp_path / "p.csv"
    path.write_text("name,x,y,z,qw,qx,qy,qz\nok.jpg,0,0,0,1,0,0,0\n" + row + "\n")
    with pytest.raises(InputError, match=fragment) as exc:
        read_poses_csv(path)
    assert str(exc.value).startswith(f"{path}:3: ")


def test_cameras_txt_round_trip_and_refusal(tmp_path):
    cams = {1: Camera(640, 480, 500.0, 501.0, 320.0, 240.0)}
    path = tmp_path / "cameras.txt"
    write_cameras_txt(path, cams)
    assert read_cameras_txt(path) == cams
    for line, fragment in [("1 OPENCV 640 480 500 500 320 240 0.1 0 0\n", "OPENCV takes 8 parameters"),
                           ("1 EQUIRECTANGULAR 640 480 640 480\n", "spherical"),
                           ("1 NO_SUCH_MODEL 640 480 500 320 240\n", "unknown camera model"),
                           ("1 SIMPLE_RADIAL 640 480 500 320 240 nan\n", "parameter k is nan"),
                           ("1 SIMPLE_RADIAL 640 480 -500 320 240 0.1\n", "positive")]:
        path.write_text("# a comment\n" + line)
        with pytest.raises(InputError, match=fragment) as exc:
            read_cameras_txt(path)
        assert str(exc.value).startswith(f"{path}:2: ")


def test_rotation_angle_scalar_and_batched():
    from sosmatch.plugin.geometry import rotation_angle_deg

    poses = _random_poses(5)
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    assert np.isclose(rotation_angle_deg(rz, np.eye(3)), 30.0)
    batched = rotation_angle_deg(poses.rotations @ rz, poses.rotations)
    assert batched.shape == (5,) and np.allclose(batched, 30.0)


def test_unreadable_inputs_name_the_file_and_its_role(tmp_path):
    with pytest.raises(InputError, match=r"missing\.csv: pose file not found"):
        read_poses_csv(tmp_path / "missing.csv")
    latin1 = tmp_path / "cameras.txt"
    latin1.write_bytes("# caméra\n".encode("latin-1"))
    with pytest.raises(InputError, match=r"cameras\.txt: cannot read cameras file: .*(?i:utf-8)"):
        read_cameras_txt(latin1)


@pytest.mark.parametrize("end", ["\r", "\r\n"])
def test_pose_csv_with_old_mac_or_windows_line_ends_reads_as_written(tmp_path, end):
    # an old-Mac editor (or Excel's "CSV (Macintosh)") ends lines with a bare CR: csv refused the whole table
    # with "do you need universal-newline mode?"
    poses = _random_poses(3)
    path = tmp_path / "poses.csv"
    write_poses_csv(path, poses)
    path.write_bytes(path.read_bytes().replace(b"\n", end.encode()))
    back, _ = read_poses_csv(path)
    assert back.names == poses.names and np.allclose(back.centers, poses.centers)
    bad = tmp_path / "bad.csv"
    bad.write_bytes(end.join(["name,x,y,z,qw,qx,qy,qz", "ok.jpg,0,0,0,1,0,0,0", "a.jpg,1,x,3,1,0,0,0", ""]).encode())
    with pytest.raises(InputError, match="non-numeric") as exc:  # line numbers still count CR-only lines
        read_poses_csv(bad)
    assert str(exc.value).startswith(f"{bad}:3: ")
