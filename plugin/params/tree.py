"""The whole parameter tree (`Params`) and its conversion to and from nested dicts and dotted overrides."""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from ..errors import InputError
from .changes import ChangeParams
from .checks import (
    Checked,
    count,
)
from .mapping import (
    ImageParams,
    KeyframeParams,
    PoseCheckParams,
    QualityParams,
    SegmentationParams,
    SfmParams,
    TrackingParams,
    TriangulationParams,
)
from .matching import AssociationParams, VerificationParams


@dataclass(frozen=True)
class Params(Checked):
    image: ImageParams = field(default_factory=ImageParams)
    keyframes: KeyframeParams = field(default_factory=KeyframeParams)
    segmentation: SegmentationParams = field(default_factory=SegmentationParams)
    tracking: TrackingParams = field(default_factory=TrackingParams)
    triangulation: TriangulationParams = field(default_factory=TriangulationParams)
    association: AssociationParams = field(default_factory=AssociationParams)
    verification: VerificationParams = field(default_factory=VerificationParams)
    changes: ChangeParams = field(default_factory=ChangeParams)
    quality: QualityParams = field(default_factory=QualityParams)
    pose_check: PoseCheckParams = field(default_factory=PoseCheckParams)
    sfm: SfmParams = field(default_factory=SfmParams)
    seed: int = count(0, 0, 2**63 - 1)  # every random choice in the pipeline derives from this


def params_to_dict(params: Any) -> dict[str, Any]:
    """Nested plain dict of a params dataclass (sections become sub-dicts)."""
    return dataclasses.asdict(params)


LATER_SECTIONS = ("association", "verification", "changes")  # the stages that read a map, never make one


def read_params(params: Params, read: tuple[str, ...],
                as_dict: Callable[[Any], dict[str, Any]] = params_to_dict) -> dict[str, Any]:
    """The settings a command reads (`read`: top-level names, i.e. sections and the seed, and dotted settings of
    other sections) as a nested dict, for the identity of its outputs: a setting it does not read then neither
    refuses nor changes them. `as_dict`: how a section becomes a dict (an identity's: `identity.params_identity`,
    or an earlier version's); section by section, so that a section not read never reaches it (an earlier
    version's refuses a setting it did not have at a non-neutral value)."""
    out = {}
    for f in dataclasses.fields(params):
        if f.name in read:
            value = getattr(params, f.name)
            out[f.name] = as_dict(value) if dataclasses.is_dataclass(value) else value
    for name in read:
        if "." in name:
            section, key = name.split(".")
            out[name] = getattr(getattr(params, section), key)
    return out


# what a map reads: every section but those of the stages after it (`LATER_SECTIONS`), and the one figure of theirs
# a map uses (theta_S, `association.min_associations`: the quality check counts the landmarks a match needs)
MAP_READS = (*(f.name for f in dataclasses.fields(Params) if f.name not in LATER_SECTIONS),
             "association.min_associations")


def mapping_params(params: Params, as_dict: Callable[[Any], dict[str, Any]] = params_to_dict) -> dict[str, Any]:
    """The parameters a map depends on (`MAP_READS`), as a nested dict (`read_params`). A batch resumes a flight's
    map while these are unchanged, so a setting of matching or change detection does not map every flight again.
    `as_dict`: how Params becomes a dict (an identity's: `identity.params_identity`, or an earlier version's)."""
    return read_params(params, MAP_READS, as_dict)


def _coerce(value: Any, annotation: Any, where: str) -> Any:
    """Check a config value against the field type; ints are accepted where floats are expected."""
    kind = {"float": float, "int": int, "str": str, "bool": bool}.get(annotation, annotation)
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if kind in (float, int, str, bool) and (type(value) is not kind):
        raise InputError(f"{where} must be {kind.__name__}, got {value!r}")
    return value


def params_from_dict(data: dict[str, Any], cls: type = Params, where: str = "") -> Any:
    """Build a params dataclass from a nested dict; missing keys keep defaults, unknown keys are an error."""
    if not isinstance(data, dict):
        raise InputError(f"{where or 'config'} must be a table, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        name = f"[{where}]" if where else "top level"
        raise InputError(f"unknown key(s) {', '.join(unknown)} in {name}; known: {', '.join(fields)}")
    kwargs = {}
    for key, value in data.items():
        path = f"{where}.{key}" if where else key
        hint = hints[key]
        if dataclasses.is_dataclass(hint):
            kwargs[key] = params_from_dict(value, hint, path)
        else:
            kwargs[key] = _coerce(value, hint, path)
            valid = fields[key].metadata.get("valid")
            if valid is not None and not valid.accepts(kwargs[key]):
                raise InputError(f"{path} must be {valid.describe()}, got {kwargs[key]!r}")
    return cls(**kwargs)


def with_overrides(params: Params, overrides: dict[str, Any]) -> Params:
    """Apply dotted-key overrides such as {"tracking.epipolar_margin_px": 8.0}."""
    data = params_to_dict(params)
    for dotted, value in overrides.items():
        *sections, key = dotted.split(".")
        node = data
        for section in sections:
            if not isinstance(node.get(section), dict):
                raise InputError(f"unknown parameter section {section!r} in {dotted!r}")
            node = node[section]
        if key not in node or isinstance(node[key], dict):
            raise InputError(f"unknown parameter {dotted!r}")
        node[key] = value
    return params_from_dict(data)
