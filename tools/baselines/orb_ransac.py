"""ORB + fundamental-matrix RANSAC baseline (paper: 500 ORB features per keyframe)."""

from __future__ import annotations

import cv2
import numpy as np

from .base import BaselineConfig, Features, extract_with, match_all

NAME = "ORB+RANSAC"


def extract(images: list[np.ndarray], config: BaselineConfig | None = None) -> Features:
    """ORB keypoints and 32-byte binary descriptors of every image (Hamming matching)."""
    config = config or BaselineConfig()
    return extract_with(cv2.ORB_create(nfeatures=config.max_features), images, cv2.NORM_HAMMING, 32, np.uint8)


__all__ = ["NAME", "extract", "match_all"]
