"""Segmentation backends: a small registry in the spirit of hloc's `extractors/`.

Each backend is a module here with a `default_conf` dict and a `make(params) -> Backend` factory; a Backend is
a callable `image (H, W, 3) uint8 RGB -> MaskSet`. A backend that reads model files also has
`model_files(params) -> {setting: absolute path}` (the files its settings or the environment name): outputs are
keyed by those files' contents (`database.segmentation_models`), not by the settings alone. The backend is
chosen by name (`segmentation.backend`). Modules are imported only when their backend is asked for, so e.g.
onnxruntime is not loaded for `classical`.
"""

from __future__ import annotations

import importlib
from dataclasses import replace
from pathlib import Path
from types import ModuleType

from ..errors import InputError
from ..params import SegmentationParams
from .base import Backend, MaskSet, mask_iou_matrix

#: name -> module (relative to this package)
BACKENDS: dict[str, str] = {
    "classical": ".classical",
    "sam-onnx": ".sam_onnx",
}

__all__ = ["BACKENDS", "Backend", "MaskSet", "get_backend", "mask_iou_matrix", "model_files", "with_model_files"]


def _module(name: str) -> ModuleType:
    if name not in BACKENDS:
        raise InputError(f"unknown segmentation backend {name!r}; known: {', '.join(sorted(BACKENDS))}")
    return importlib.import_module(BACKENDS[name], __name__)


def get_backend(name: str, params: SegmentationParams) -> Backend:
    """The backend registered as `name`, configured from `params` (raises InputError for unknown names)."""
    return _module(name).make(params)


def model_files(params: SegmentationParams) -> dict[str, Path]:
    """The model files the backend `params.backend` reads, by the setting naming each, resolved now (from the
    settings or the environment) to absolute paths; {} for a backend without any (`classical`). InputError for an
    unknown backend or a missing file."""
    files = getattr(_module(params.backend), "model_files", None)
    return {} if files is None else files(params)


def with_model_files(params: SegmentationParams, files: dict[str, Path]) -> SegmentationParams:
    """`params` naming `files` (`model_files`) in their settings: a backend built from them reads those files
    whatever the environment says later (worker processes, a later run in the same process)."""
    return replace(params, **{name: str(path) for name, path in files.items()}) if files else params
