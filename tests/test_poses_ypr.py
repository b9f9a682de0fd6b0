"""Pose CSV with yaw/pitch/roll columns (aerospace angles of the camera body)."""

import numpy as np
import pytest

from sosmatch.database.poses import read_poses_csv, rotmat_to_ypr, ypr_to_rotmat
from sosmatch.plugin.errors import InputError


def test_nadir_and_heading_conventions():
    nadir = ypr_to_rotmat([0.0], [-90.0], [0.0])[0]
    # Optical axis down, image right = east, image down = south (image top towards the heading, north).
    assert np.allclose(nadir[:, 2], [0, 0, -1]) and np.allclose(nadir[:, 0], [1, 0, 0])
    assert np.allclose(nadir[:, 1], [0, -1, 0])
    east = ypr_to_rotmat([90.0], [0.0], [0.0])[0]
    assert np.allclose(east[:, 2], [1, 0, 0]) and np.allclose(east[:, 1], [0, 0, -1])
    rolled = ypr_to_rotmat([0.0], [0.0], [30.0])[0]  # right side down: image right tilts below the horizon
    assert rolled[2, 0] < -0.4


def test_angles_round_trip():
    rng = np.random.default_rng(0)
    ypr = np.stack([rng.uniform(-179, 179, 40), rng.uniform(-89, 89, 40), rng.uniform(-179, 179, 40)], 1)
    rot = ypr_to_rotmat(*ypr.T)
    assert np.allclose(np.einsum("nji,njk->nik", rot, rot), np.eye(3), atol=1e-12)
    assert np.allclose(rotmat_to_ypr(rot), ypr, atol=1e-9)


def test_ypr_csv_matches_the_quaternion_csv(tmp_path):
    ypr = tmp_path / "ypr.csv"
    ypr.write_text("# convention: world_from_camera\nname,x,y,z,yaw_deg,pitch_deg,roll_deg\n"
                   "a.jpg,1,2,100,0,-90,0\nb.jpg,3,4,100,90,0,0\n")
    poses, epsg = read_poses_csv(ypr)
    assert epsg == 0 and poses.names == ["a.jpg", "b.jpg"]
    quat = tmp_path / "q.csv"
    quat.write_text("name,x,y,z,qw,qx,qy,qz\na.jpg,1,2,100,0,1,0,0\n")
    q_poses, _ = read_poses_csv(quat)
    assert np.allclose(poses.rotations[0], q_poses.rotations[0]) and np.allclose(poses.centers[0], [1, 2, 100])
    inverted, _ = read_poses_csv(ypr, convention="camera_from_world")
    assert np.allclose(inverted.rotations, np.transpose(poses.rotations, (0, 2, 1)))


@pytest.mark.parametrize("row, fragment", [
    ("a.jpg,1,2,3,inf,0,0", "NaN or infinite"),
    ("a.jpg,1,2,3,0,0", "columns"),
    ("a.jpg,1,2,3,north,0,0", "non-numeric"),
])
def test_bad_ypr_rows_name_file_and_line(tmp_path, row, fragment):
    path = tmp_path / "p.csv"
    path.write_text("name,x,y,z,yaw_deg,pitch_deg,roll_deg\nok.jpg,0,0,0,0,-90,0\n" + row + "\n")
    with pytest.raises(InputError, match=fragment) as exc:
        read_poses_csv(path)
    assert str(exc.value).startswith(f"{path}:3: ")


def test_yaw_in_a_projected_crs_is_from_true_north(tmp_path):
    """The ninth new-user sweep: gimbal yaw (from true north) in a UTM pose CSV was read as a grid azimuth, 1.5 deg
    off at Seneca (16 landmarks instead of 75). In a projected CRS it is turned by the meridian convergence."""
    from sosmatch.plugin.geodesy import geographic_to_grid

    e, n, north_az = geographic_to_grid(np.array([42.9]), np.array([-76.9]), 32617)  # east of the zone's centre
    assert abs(north_az[0]) > 1.0
    path = tmp_path / "p.csv"
    path.write_text(f"# crs: EPSG:32617\nname,x,y,z,yaw_deg,pitch_deg,roll_deg\na.jpg,{e[0]},{n[0]},300,0,-90,0\n")
    poses, epsg = read_poses_csv(path)
    top = -poses.rotations[0][:, 1]  # image top: towards true north
    assert epsg == 32617 and np.degrees(np.arctan2(top[0], top[1])) == pytest.approx(north_az[0], abs=1e-6)
    local = tmp_path / "l.csv"
    local.write_text(path.read_text().replace("EPSG:32617", "local"))
    top = -read_poses_csv(local)[0].rotations[0][:, 1]
    assert np.degrees(np.arctan2(top[0], top[1])) == pytest.approx(0.0, abs=1e-9)  # a local frame's north is +y


def test_longitude_latitude_given_as_x_y_are_named(tmp_path):
    path = tmp_path / "p.csv"
    rows = "".join(f"f{k}.jpg,{-76.9 + k * 1e-5},{42.9 + k * 1e-5},300,0,-90,0\n" for k in range(5))
    path.write_text("# crs: EPSG:32617\nname,x,y,z,yaw_deg,pitch_deg,roll_deg\n" + rows)
    with pytest.raises(InputError, match="look like longitude / latitude in degrees"):
        read_poses_csv(path)


def test_angles_in_a_crs_far_outside_its_area_are_refused(tmp_path):
    """True north needs the CRS's own area: local coordinates stamped with a UTM zone gave a made-up convergence."""
    path = tmp_path / "p.csv"
    path.write_text("# crs: EPSG:32617\nname,x,y,z,yaw_deg,pitch_deg,roll_deg\n"
                    + "".join(f"f{k}.jpg,{50 * k},0,300,0,-90,0\n" for k in range(3)))
    with pytest.raises(InputError, match="the camera centres lie at x 0..100"):
        read_poses_csv(path)


@pytest.mark.parametrize("epsg, problem", [
    (3857, r"EPSG:3857 \(WGS 84 / Pseudo-Mercator\) stretches distances by 1\.36.*UTM zone 18N \(EPSG:32618\)"),
    (2263, r"measures in US survey foot; poses need a projected CRS in metres"),
])
def test_a_crs_that_does_not_keep_metres_at_the_site_is_refused(tmp_path, epsg, problem):
    """The thirteenth sweep: UTM poses re-projected to Web Mercator (a GIS export) mapped with exit 0, the landmarks
    48 m below the ground and 1.46 x their size; a CRS in feet would be read as metres."""
    from pyproj import Transformer

    x, y = Transformer.from_crs(4326, epsg, always_xy=True).transform(-76.9, 42.9)
    path = tmp_path / "p.csv"
    path.write_text(f"# crs: EPSG:{epsg}\nname,x,y,z,yaw_deg,pitch_deg,roll_deg\n"
                    + "".join(f"f{k}.jpg,{x + 20 * k},{y},300,0,-90,0\n" for k in range(3)))
    with pytest.raises(InputError, match=problem):
        read_poses_csv(path)
    utm = Transformer.from_crs(4326, 32617, always_xy=True).transform(-76.9, 42.9)
    path.write_text("# crs: EPSG:32617\nname,x,y,z,yaw_deg,pitch_deg,roll_deg\n"
                    + "".join(f"f{k}.jpg,{utm[0] + 20 * k},{utm[1]},300,0,-90,0\n" for k in range(3)))
    assert read_poses_csv(path)[1] == 32617
