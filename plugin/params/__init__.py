"""Every parameter of the method, with the paper's defaults, in one frozen dataclass tree.

Field comments give the symbol used in SOS-Match (Thomas et al., IROS 2024) and the method's specification
(kept outside this repository).
Values marked *(ours)* are not fixed by the paper; the module that uses them documents how they were chosen.
Parameters are plain data: `params_from_dict` / `params_to_dict` convert to and from nested dicts (TOML lives in
`sosmatch.database.config_io`), and unknown keys are rejected rather than silently ignored.

One module per part: `checks` (valid values), `mapping`, `matching`, `changes` (the stages' sections),
`tree` (`Params` and its dict conversion), `presets` (named presets, scaling to an image size); every name is
imported from here, `sosmatch.plugin.params`.
"""

from .changes import ChangeParams
from .checks import (
    MAX_COUNT,
    Checked,
    Valid,
    count,
    flag,
    fraction,
    non_negative,
    one_of,
    positive,
    text,
    valid_values,
    within,
)
from .identity import ADDED, IdentityVersions, identity_versions, params_identity
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
from .presets import (
    PIXEL_AREAS,
    PIXEL_LENGTHS,
    PRESETS,
    for_flight,
    for_ground_resolution,
    for_image,
    pixel_scale,
    preset_params,
    survey_preset_remedy,
)
from .tree import (
    LATER_SECTIONS,
    MAP_READS,
    Params,
    mapping_params,
    params_from_dict,
    params_to_dict,
    read_params,
    with_overrides,
)

__all__ = [
    "ADDED",
    "IdentityVersions",
    "identity_versions",
    "params_identity",
    "AssociationParams",
    "ChangeParams",
    "Checked",
    "ImageParams",
    "KeyframeParams",
    "LATER_SECTIONS",
    "MAP_READS",
    "MAX_COUNT",
    "PIXEL_AREAS",
    "PIXEL_LENGTHS",
    "PRESETS",
    "Params",
    "PoseCheckParams",
    "QualityParams",
    "SegmentationParams",
    "SfmParams",
    "TrackingParams",
    "TriangulationParams",
    "Valid",
    "VerificationParams",
    "count",
    "flag",
    "for_flight",
    "for_ground_resolution",
    "for_image",
    "fraction",
    "mapping_params",
    "read_params",
    "non_negative",
    "one_of",
    "params_from_dict",
    "params_to_dict",
    "pixel_scale",
    "positive",
    "preset_params",
    "survey_preset_remedy",
    "text",
    "valid_values",
    "with_overrides",
    "within",
]
