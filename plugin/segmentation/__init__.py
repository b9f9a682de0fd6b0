"""Segmentation backends: a small registry in the spirit of hloc's `extractors/`.

Each backend is a module here with a `default_conf` dict and a `make(params) -> Backend` factory; a Backend is
a callable `image (H, W, 3) uint8 RGB -> MaskSet`. The backend is chosen by name (`segmentation.backend`).
Modules are imported only when their backend is asked for, so e.g. onnxruntime is not loaded for `classical`.
"""

from __future__ import annotations

import importlib

from ..errors import InputError
from ..params import SegmentationParams
from .base import Backend, MaskSet, mask_iou_matrix

#: name -> module (relative to this package)
BACKENDS: dict[str, str] = {
    "classical": ".classical",
    "sam-onnx": ".sam_onnx",
}

__all__ = ["BACKENDS", "Backend", "MaskSet", "get_backend", "mask_iou_matrix"]


def get_backend(name: str, params: SegmentationParams) -> Backend:
    """The backend registered as `name`, configured from `params` (raises InputError for unknown names)."""
    if name not in BACKENDS:
        raise InputError(f"unknown segmentation backend {name!r}; known: {', '.join(sorted(BACKENDS))}")
    module = importlib.import_module(BACKENDS[name], __name__)
    return module.make(params)
