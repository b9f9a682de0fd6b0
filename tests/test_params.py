"""Parameters: paper defaults, TOML round trip, unknown keys rejected, overrides typed."""

import pytest

from sosmatch.database.config_io import dump_params, load_params, parse_override
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.params import Params, params_to_dict


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

    assert preset_params("paper") == Params()
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
