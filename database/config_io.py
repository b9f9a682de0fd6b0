"""TOML load/dump of `sosmatch.plugin.params.Params`, with file-naming errors."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import tomli_w

from ..plugin.errors import InputError
from ..plugin.params import Params, params_from_dict, params_to_dict, preset_params, with_overrides
from .text_input import read_user_text

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def load_params(
    path: str | Path | None = None, overrides: dict[str, Any] | None = None, preset: str | None = None
) -> Params:
    """Defaults (or the named preset, see `sosmatch.plugin.params.PRESETS`), then the TOML file (if any), then
    dotted overrides. Unknown keys are an error."""
    params = preset_params(preset) if preset else Params()
    if path is not None:
        path = Path(path)
        data = _read_config(path)
        try:
            params = params_from_dict(data) if not preset else with_overrides(params, _dotted(data))
        except InputError as exc:
            raise InputError(exc.problem, path) from None
    if overrides:
        params = with_overrides(params, overrides)
    return params


def _read_config(path: Path) -> dict[str, Any]:
    try:
        return tomllib.loads(read_user_text(path, "config file"))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"invalid TOML: {exc}", path) from None


def chosen_settings(
    path: str | Path | None = None, overrides: dict[str, Any] | None = None, preset: str | None = None
) -> set[str]:
    """The dotted names of the settings the user chose (as `load_params` reads them: the preset's, the TOML file's
    and the overrides'), whatever their values: a command whose default depends on its inputs
    (`workflows.match.transform_choice`) leaves a chosen one as it is."""
    from ..plugin.params import PRESETS

    named = set(PRESETS.get(preset, {})) if preset else set()
    if path is not None:
        named |= set(_dotted(_read_config(Path(path))))
    return named | set(overrides or {})


def _dotted(data: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """{"tracking": {"min_score": 0.3}} -> {"tracking.min_score": 0.3} (a config file on top of a preset)."""
    flat: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            flat.update(_dotted(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def dump_params(params: Params) -> str:
    """TOML text of the parameters (round-trips through `load_params`)."""
    return tomli_w.dumps(params_to_dict(params))


def parse_override(text: str) -> tuple[str, Any]:
    """Parse one `section.key=value` flag; the value is read as a TOML literal, else kept as a string."""
    if "=" not in text:
        raise InputError(f"--set expects section.key=value, got {text!r}")
    key, raw = (part.strip() for part in text.split("=", 1))
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return key, value
