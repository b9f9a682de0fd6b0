"""Parameters: paper defaults, TOML round trip, unknown keys rejected, overrides typed."""

import dataclasses
import math

import pytest

from sosmatch.database.config_io import dump_params, load_params, parse_override
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.params import Params, params_to_dict, preset_params, with_overrides


def test_paper_defaults():
    p = Params()
    assert p.keyframes.interval_m == 2.0
    assert p.tracking.motion_gate_sigmas == 4.0 and p.tracking.min_score == 0.2
    assert p.tracking.size_tolerance == 0.2 and p.triangulation.min_observations == 5
    assert p.triangulation.pixel_sigma_px == 3.0
    a = p.association
    assert (a.window_length, a.window_stride, a.max_size_difference) == (50, 10, 0.2)
    assert (a.distance_tolerance_m, a.max_gravity_angle_deg) == (2.0, 22.5)


def test_toml_round_trip(tmp_path):
    p = load_params(None, {"tracking.epipolar_margin_px": 7.5, "association.window_length": 40, "seed": 3})
    path = tmp_path / "p.toml"
    path.write_text(dump_params(p))
    q = load_params(path)
    assert q == p
    assert params_to_dict(q)["association"]["window_length"] == 40


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("[tracking]\nbogus = 1\n", "bogus"),
        ("[nosection]\nx = 1\n", "nosection"),
        ("[association]\nwindow_length = 'fifty'\n", "association.window_length"),
        ("this is not toml", "invalid TOML"),
    ],
)
def test_bad_config_names_file_and_problem(tmp_path, text, fragment):
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(InputError) as exc:
        load_params(path)
    assert str(path) in str(exc.value) and fragment in str(exc.value)


def test_missing_config_file(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_params(tmp_path / "nope.toml")


def test_override_parsing_and_rejection():
    assert parse_override("tracking.epipolar_margin_px=8") == ("tracking.epipolar_margin_px", 8)
    assert parse_override("segmentation.backend=sam-onnx") == ("segmentation.backend", "sam-onnx")
    p = load_params(None, dict([parse_override("tracking.epipolar_margin_px=8")]))
    assert p.tracking.epipolar_margin_px == 8.0 and isinstance(p.tracking.epipolar_margin_px, float)
    with pytest.raises(InputError):
        load_params(None, {"tracking.nope": 1})
    with pytest.raises(InputError):
        parse_override("no-equals-sign")


def test_presets_layer_under_config_file_and_set(tmp_path):
    from sosmatch.plugin.params import PRESETS, preset_params

    # the paper's method differs from the defaults only in how the search forms and solves its graphs, in its
    # fixed tolerances (not derived from the maps' noise) and same-length windows in both maps, in the front end's
    # track fusion, size estimator and fixed theta_n and in tracking's ground band gate and cut (truncated) views
    paper = preset_params("paper")
    base = Params()
    assert dataclasses.replace(paper, association=base.association, triangulation=base.triangulation,
                               tracking=base.tracking) == base
    assert dataclasses.replace(paper.tracking, ground_band_sigmas=base.tracking.ground_band_sigmas,
                               truncation_aware=True) == base.tracking
    assert paper.tracking.ground_band_sigmas == 0.0 < base.tracking.ground_band_sigmas
    assert not paper.tracking.truncation_aware and base.tracking.truncation_aware  # cut views: ours, on (fix76)
    assert set(PRESETS["paper"]) == {"association.consistency", "association.windows", "association.position_prior_m",
                                     "association.georeference_prior_m", "association.solver",
                                     "association.derive_from_maps",
                                     "association.equal_area_windows",
                                     "triangulation.size_estimator", "triangulation.fuse_radius_factor",
                                     "triangulation.min_observations_from_views", "tracking.ground_band_sigmas",
                                     "triangulation.whole_masks_only", "tracking.truncation_aware"}
    assert dataclasses.replace(paper.triangulation, size_estimator="nadir", fuse_radius_factor=2.0,
                               min_observations_from_views=True, whole_masks_only=True) == Params().triangulation
    survey = preset_params("survey")
    for dotted, value in PRESETS["survey"].items():
        section, key = dotted.split(".")
        assert getattr(getattr(survey, section), key) == value
    assert survey.association == Params().association  # a preset changes only what it names
    # a config file on top of a preset changes only its own keys; --set wins over both
    cfg = tmp_path / "c.toml"
    cfg.write_text("[tracking]\nmin_score = 0.35\n")
    p = load_params(cfg, {"tracking.epipolar_margin_px": 30.0}, preset="survey")
    assert p.tracking.min_score == 0.35 and p.tracking.epipolar_margin_px == 30.0
    assert p.triangulation.min_observations == survey.triangulation.min_observations
    with pytest.raises(InputError, match="unknown preset 'nope'.*paper, survey"):
        load_params(None, None, preset="nope")


def test_config_dump_with_preset_cli(capsys):
    from sosmatch.tools.cli import main

    assert main(["config", "dump", "--preset", "survey"]) == 0
    assert "min_observations = 2" in capsys.readouterr().out


def _leaf_fields(cls=None, prefix=""):
    """(dotted name, owning class, field) of every parameter, recursively."""
    import dataclasses
    import typing

    cls = cls or Params
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(hints[f.name]):
            yield from _leaf_fields(hints[f.name], f"{prefix}{f.name}.")
        else:
            yield f"{prefix}{f.name}", cls, f


def test_every_parameter_declares_its_valid_values():
    # A field added later must declare its range or choices (plugin/params/checks.py: within, positive, count, one_of,
    # flag, text); this test is what makes that so.
    missing = [name for name, _, f in _leaf_fields() if "valid" not in f.metadata]
    assert not missing, f"parameters without a valid-values declaration: {missing}"
    for name, _, f in _leaf_fields():
        assert f.metadata["valid"].accepts(f.default), f"{name}: default {f.default!r} outside its own declaration"


def test_presets_respect_the_declarations():
    from sosmatch.plugin.params import PRESETS, preset_params

    for name in PRESETS:
        preset_params(name)  # raises InputError if any override is out of range


def test_segmentation_backend_choices_are_the_registry():
    from sosmatch.plugin.params import SegmentationParams, valid_values
    from sosmatch.plugin.segmentation import BACKENDS

    assert set(valid_values(SegmentationParams, "backend").choices) == set(BACKENDS)


# rev42: each value within its range, together unusable, and once searched silently: theta_S 6 needs more than 6
# associations from a window of 3 landmarks ("no match", exit 0), and stride 100 over windows of 50 never searched
# landmarks 50-99 of every 100
WINDOWS_THAT_CANNOT_WORK = [
    ("association.window_length=3", "window_length 3 is at most association.min_associations (theta_S) 6"),
    ("association.window_length=6", "window_length 6 is at most association.min_associations (theta_S) 6"),
    ("association.window_stride=100", "window_stride 100 exceeds association.window_length 50"),
]


@pytest.mark.parametrize("override, fragment", [
    ("association.affinity_sigma_m=nan", "association.affinity_sigma_m must be within [0.001, 1000]"),
    # values the checks once let through into a MemoryError, a ZeroDivisionError, an OverflowError or 31 GiB
    ("association.yaw_slice_deg=1e-9", "yaw_slice_deg must be 0 (off) or within [0.5, 180]"),
    ("association.affinity_sigma_m=1e-300", "affinity_sigma_m must be within [0.001, 1000]"),
    ("association.distance_tolerance_m=1e300", "distance_tolerance_m must be within [0.001, 1000]"),
    ("association.min_associations=2000000", "min_associations must be within [2, 1000000]"),
    ("verification.chance_starts=1000000000", "chance_starts must be within [0, 100000]"),
    ("changes.probe_count=100000000", "probe_count must be within [1, 360]"),
    ("changes.unmapped_pixel_sigma_px=1e300", "unmapped_pixel_sigma_px must be within (0, 10000]"),
    ("changes.surface_views=1000000", "surface_views must be within [2, 100]"),
    ("triangulation.min_observations=-5", "triangulation.min_observations must be within [1, 2147483647]"),
    # an integer beyond a C int once reached numba (a 40-line traceback) and COLMAP's options
    ("association.window_length=99999999999999999999999", "window_length must be within [3, 2147483647]"),
    ("sfm.max_features=4294967296", "sfm.max_features must be within [64, 2147483647]"),
    ("verification.min_ratio=0.5", "verification.min_ratio must be within [1, inf)"),  # a winner weaker than its rival
    ("association.transform='affine'", "one of 'rigid', 'similarity'"),
    ("segmentation.classical_median_ksize=4", "odd"),
    ("tracking.min_score=1.5", "within [0, 1]"),
    ("keyframes.interval_m=inf", "within (0, inf)"),
    *WINDOWS_THAT_CANNOT_WORK,
])
def test_out_of_range_values_are_refused_by_config_check(tmp_path, capsys, override, fragment):
    from sosmatch.tools.cli import main

    assert main(["config", "check", "--set", override]) == 2
    err = capsys.readouterr().err
    assert fragment in err and len(err.strip().splitlines()) == 1
    cfg = tmp_path / "c.toml"
    section, kv = override.split(".", 1)
    cfg.write_text(f"[{section}]\n{kv}\n")
    assert main(["config", "check", "--config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert str(cfg) in err and fragment.split(" must")[-1].strip() in err


def test_config_check_says_what_it_checked_and_takes_the_off_value(capsys):
    from sosmatch.tools.cli import main

    assert main(["config", "check", "--preset", "paper", "--set", "association.yaw_slice_deg=0"]) == 0
    assert capsys.readouterr().out.strip() == "preset paper + --set association.yaw_slice_deg=0: ok"  # was "defaults"
    assert main(["config", "check"]) == 0 and capsys.readouterr().out.strip() == "defaults: ok"


def test_direct_construction_is_checked_too():
    import dataclasses

    from sosmatch.plugin.params import AssociationParams

    with pytest.raises(InputError, match="AssociationParams.affinity_sigma_m"):
        AssociationParams(affinity_sigma_m=float("nan"))
    with pytest.raises(InputError, match="window_length"):
        dataclasses.replace(Params().association, window_length=0)


def test_pixel_limits_scale_with_the_image_and_stay_at_the_tuned_size():
    from sosmatch.plugin.params import PIXEL_AREAS, PIXEL_LENGTHS, for_image, pixel_scale

    survey = preset_params("survey")
    assert for_image(survey, 1200, 900) is survey and for_image(survey, 640, 480) is survey  # tuned / smaller
    assert pixel_scale(Params(), 640, 480) == 1.0 and pixel_scale(survey, 900, 1200) == 1.0  # portrait too
    big = for_image(survey, 4000, 2250)  # a DJI 16:9 frame: the longer side counts
    s = 4000 / 1200
    assert math.isclose(big.tracking.epipolar_margin_px, 24.0 * s)
    assert math.isclose(big.triangulation.max_reprojection_error_px, 8.0 * s)
    assert math.isclose(big.triangulation.pixel_sigma_px, 6.0 * s)
    assert math.isclose(big.tracking.centroid_sigma_px, 9.0 * s)
    assert big.segmentation.classical_min_area_px == round(100 * s * s)
    assert isinstance(big.segmentation.min_mask_area_px, int)
    assert len(PIXEL_LENGTHS) == 4 and len(PIXEL_AREAS) == 2
    # everything else is untouched
    assert big.tracking.size_tolerance == survey.tracking.size_tolerance and big.association == survey.association
    paper = for_image(Params(), 1280, 960)
    assert math.isclose(paper.tracking.epipolar_margin_px, 24.0)
    off = with_overrides(Params(), {"image.reference_size_px": 0.0})
    assert for_image(off, 4000, 3000) is off


def test_the_segmenters_working_pixel_is_never_coarser_than_its_ground_target():
    from sosmatch.plugin.params import for_ground_resolution

    p = Params()
    target = p.segmentation.classical_ground_resolution_m
    # 640 px frames (f 502 px): at 70-100 m the fixed 400 px already meet the target and the floor (unchanged: the
    # parameters were tuned there), and so at 70 m with the measured flying height 3 % low
    for altitude in (0.97 * 70.0, 80.0, 100.0):
        assert for_ground_resolution(p, altitude / 502.3, 640, 480) is p
    # higher, the working size grows so that one working pixel covers at most `target` metres
    for altitude in (110.0, 130.0, 150.0):
        gsd = altitude / 502.3
        q = for_ground_resolution(p, gsd, 640, 480)
        side = q.segmentation.classical_max_side
        assert 400 < side <= 640 and gsd * 640 / side <= target < gsd * 640 / (side - 1)
        # the smallest region keeps its number of working pixels (as at 400 px), so its ground area
        working_area = q.segmentation.classical_min_area_px * (side / 640) ** 2
        assert abs(working_area - 100 * (400 / 640) ** 2) <= 0.6 * (side / 640) ** 2
    # at most the full size (imagery at the target: every pixel counts)
    assert for_ground_resolution(p, target, 640, 480).segmentation.classical_max_side == 640
    # never more than twice the fixed size: a 40 Mpx frame at 0.3 m/px is not segmented whole
    assert for_ground_resolution(p, 0.3, 7300, 5500).segmentation.classical_max_side == 800
    # a 5472 px drone frame at 120 m (3.2 cm/px): 0.44 m per working pixel at 400 px, so 531 px
    assert for_ground_resolution(p, 0.032, 5472, 3648).segmentation.classical_max_side == 531
    # a 4000 px drone frame at 100 m (2.7 cm/px): 400 px make 0.27 m, within the target
    assert for_ground_resolution(p, 0.027, 4000, 3000) is p
    # unchanged when unknown, switched off, for another backend, or for imagery coarser than the target (an
    # orthophoto's views: no working size reaches it, the fixed one stays)
    assert for_ground_resolution(p, float("nan"), 640, 480) is p
    assert for_ground_resolution(p, 2.5, 640, 480) is p and for_ground_resolution(p, 1.01 * target, 640, 480) is p
    assert for_ground_resolution(p, 0.0, 640, 480) is p
    off = with_overrides(p, {"segmentation.classical_ground_resolution_m": 0.0})
    assert for_ground_resolution(off, 0.26, 640, 480) is off
    sam = with_overrides(p, {"segmentation.backend": "sam-onnx"})
    assert for_ground_resolution(sam, 0.26, 640, 480) is sam


def test_the_segmenters_working_pixel_is_never_finer_than_its_ground_floor():
    from sosmatch.plugin.params import for_ground_resolution

    p = Params()
    floor = p.segmentation.classical_min_ground_resolution_m
    assert 0 < floor < p.segmentation.classical_ground_resolution_m
    # a zoom camera (hfov 30 deg, f 1194 px) at 120 m: 0.10 m per pixel, 0.16 m per working pixel at 400 px;
    # the working side shrinks to the largest whose pixel covers at least the floor
    gsd = 120.0 / 1194.3
    q = for_ground_resolution(p, gsd, 640, 480)
    side = q.segmentation.classical_max_side
    assert side < 400 and gsd * 640 / (side + 1) < floor <= gsd * 640 / side
    # the smallest region keeps its number of working pixels, so its ground area is the tuned one at the floor
    working_area = q.segmentation.classical_min_area_px * (side / 640) ** 2
    assert abs(working_area - 100 * (400 / 640) ** 2) <= 0.6 * (side / 640) ** 2
    # everything else is untouched
    assert q.segmentation.classical_median_ksize == p.segmentation.classical_median_ksize
    assert q.tracking == p.tracking and q.triangulation == p.triangulation
    # a low flight (640 px, f 502 px, 40 m): 0.13 m per working pixel at 400 px, the floor after
    low = for_ground_resolution(p, 40.0 / 502.3, 640, 480).segmentation.classical_max_side
    assert 40.0 / 502.3 * 640 / low >= floor and low < 400
    # Seneca (1200 px, 0.0757 m per pixel as its pose check measures it: 0.227 m per working pixel at 400 px), and
    # that measurement 3 % low, keep the fixed size: coarser, its survey map lost landmarks (0.24 m: 370 -> 328)
    for seneca in (0.0757, 0.97 * 0.0757):
        assert for_ground_resolution(p, seneca, 1200, 900) is p
    # a 4000 px frame at 100 m (2.7 cm per pixel, 0.27 m per working pixel): within both bounds
    assert for_ground_resolution(p, 0.027, 4000, 3000) is p
    # switched off, another backend, unknown resolution: unchanged
    off = with_overrides(p, {"segmentation.classical_min_ground_resolution_m": 0.0})
    assert for_ground_resolution(off, gsd, 640, 480) is off
    sam = with_overrides(p, {"segmentation.backend": "sam-onnx"})
    assert for_ground_resolution(sam, gsd, 640, 480) is sam
    assert for_ground_resolution(p, float("nan"), 640, 480) is p
    # a floor above the ceiling is held at the ceiling: the working pixel is never pushed past the tuned one
    inverted = with_overrides(p, {"segmentation.classical_min_ground_resolution_m": 0.5})
    side = for_ground_resolution(inverted, gsd, 640, 480).segmentation.classical_max_side
    assert gsd * 640 / side <= 0.5 and gsd * 640 / side >= p.segmentation.classical_ground_resolution_m


@pytest.mark.parametrize("override, fragment", WINDOWS_THAT_CANNOT_WORK)
def test_windows_that_cannot_work_are_refused_in_python_too(override, fragment):
    """The check is the parameters' own: a Python user's AssociationParams is refused as the CLI's is."""
    import dataclasses

    from sosmatch.plugin.params import AssociationParams

    key, value = override.split(".", 1)[1].split("=")
    with pytest.raises(InputError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
        dataclasses.replace(AssociationParams(), **{key: int(value)})


def test_windows_at_the_edge_of_working_are_kept(capsys):
    from sosmatch.tools.cli import main

    # a window one landmark longer than theta_S can hold a match; a stride equal to the length leaves no gap
    assert main(["config", "check", "--set", "association.window_length=7", "--set",
                 "association.window_stride=7"]) == 0
    assert main(["config", "check", "--set", "association.min_associations=49"]) == 0
