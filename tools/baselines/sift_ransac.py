"""SIFT + fundamental-matrix RANSAC baseline (paper: 500 SIFT features per keyframe)."""

from __future__ import annotations

import cv2
import numpy as np

from .base import BaselineConfig, Features, extract_with, match_all

NAME = "SIFT+RANSAC"


def extract(images: list[np.ndarray], config: BaselineConfig | None = None) -> Features:
    """SIFT keypoints and 128-float descriptors (512 bytes each) of every image (L2 matching)."""
    config = config or BaselineConfig()
    return extract_with(cv2.SIFT_create(nfeatures=config.max_features), images, cv2.NORM_L2, 128, np.float32)


__all__ = ["NAME", "extract", "match_all"]
