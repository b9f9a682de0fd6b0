"""`sam-onnx`: Segment Anything family through onnxruntime (no torch), in "segment everything" mode.

Models: an image-encoder ONNX and a prompt-decoder ONNX (paths from `segmentation.sam_encoder` /
`segmentation.sam_decoder`, else the environment variables `SOSMATCH_SAM_ENCODER` / `SOSMATCH_SAM_DECODER`).
Supported exports, recognised from the session's input names and shapes:

encoders
- samexporter `--use-preprocess` (SAM ViT-B/L/H, MobileSAM): input (h, w, 3) float32 RGB 0..255, the image
  resized so its longer side is 1024; normalisation and padding happen inside the model;
- plain encoder (samexporter without preprocessing, or a direct export of `sam.image_encoder`):
  input (1, 3, S, S) float32, normalised with SAM's pixel mean / std and zero-padded to S (1024);
- EfficientSAM: input `batched_images` (1, 3, H, W) float32 RGB 0..1 at the original size.
The first output is the image embedding (1, 256, 64, 64).

decoders
- SAM's official export (`scripts/export_onnx_model.py`, also samexporter's): inputs `image_embeddings`
  (1, 256, 64, 64), `point_coords` (B, N, 2), `point_labels` (B, N), `mask_input` (1, 1, 256, 256),
  `has_mask_input` (1), `orig_im_size` (2); outputs `masks`, `iou_predictions`, `low_res_masks`. Coordinates
  are in the 1024-resized frame. B > 1 (batched prompts) is used when the export left the batch axis dynamic.
- EfficientSAM: inputs `image_embeddings`, `batched_point_coords` (1, Q, N, 2), `batched_point_labels`
  (1, Q, N), `orig_im_size` (2, int64); outputs masks (1, Q, C, H, W) and IoU predictions (1, Q, C);
  coordinates in original pixels.

Automatic mask generation follows SAM's `SamAutomaticMaskGenerator`: a grid of `points_per_side`^2 single
point prompts, decoded in batches with multimask output; candidates are filtered by predicted IoU and by the
stability score (IoU of the mask thresholded at +offset and -offset), then duplicates are removed by greedy
mask NMS (highest predicted IoU first). Stability is computed on the 256x256 low-resolution logits (cheap; the
full-resolution mask of every rejected candidate would cost more than the decoder) and only survivors are
upsampled to the image size, where they are stored as bounding-box crops.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from ..params import SegmentationParams
from .base import Backend, MaskSet, mask_iou_matrix

log = logging.getLogger(__name__)

PIXEL_MEAN = np.array([123.675, 116.28, 103.53], np.float32)
PIXEL_STD = np.array([58.395, 57.12, 57.375], np.float32)
SAM_DECODER_INPUTS = {"image_embeddings", "point_coords", "point_labels", "mask_input", "has_mask_input",
                      "orig_im_size"}
EFFICIENTSAM_DECODER_INPUTS = {"image_embeddings", "batched_point_coords", "batched_point_labels", "orig_im_size"}
EXPORT_HINT = ("export the models as described in the README (section \"Exporting SAM models to ONNX\" under "
               "\"Segmentation\") and set segmentation.sam_encoder / sam_decoder or SOSMATCH_SAM_ENCODER / "
               "SOSMATCH_SAM_DECODER")


def _static(dim: object) -> int | None:
    """An ONNX dimension as int if fixed, None if symbolic / unknown."""
    return dim if isinstance(dim, int) and dim > 0 else None


def _check_shape(path: Path, name: str, shape: list, expected: tuple) -> None:
    """Fail if a fixed dimension of `shape` contradicts `expected` (None in expected = anything)."""
    if len(shape) != len(expected) or any(
        _static(d) is not None and e is not None and _static(d) != e for d, e in zip(shape, expected)
    ):
        want = "(" + ", ".join("?" if e is None else str(e) for e in expected) + ")"
        raise InputError(f"ONNX input/output {name!r} has shape {list(shape)}, expected {want}", path)


def resolve_model_path(configured: str, env: str, role: str) -> Path:
    """The model file from the config value or the environment; InputError if unset or missing."""
    value = configured or os.environ.get(env, "")
    if not value:
        raise InputError(f"no SAM {role} ONNX given (segmentation.sam_{role} or ${env}); {EXPORT_HINT}")
    path = Path(value).expanduser()
    if not path.is_file():
        raise InputError(f"SAM {role} ONNX file not found; {EXPORT_HINT}", path)
    return path


def model_files(params: SegmentationParams) -> dict[str, Path]:
    """The encoder and decoder files `params` names (or the environment, when unset), by the setting naming each,
    as absolute paths: what a run records and keys its outputs by (`database.segmentation_models`)."""
    return {"sam_encoder": resolve_model_path(params.sam_encoder, "SOSMATCH_SAM_ENCODER", "encoder").resolve(),
            "sam_decoder": resolve_model_path(params.sam_decoder, "SOSMATCH_SAM_DECODER", "decoder").resolve()}


def _session(path: Path, threads: int) -> object:
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = max(1, threads)
    opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    try:
        return ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own exception types for unreadable / invalid models
        raise InputError(f"not a loadable ONNX model ({type(exc).__name__}: {str(exc).splitlines()[0]})",
                         path) from None


@dataclass
class SamEncoder:
    """An image-encoder session and the preprocessing its inputs call for."""

    path: Path
    session: object
    input_name: str
    kind: str  # "hwc" | "nchw" | "efficientsam"
    target: int  # longer side of the resized image (1024); 0 for efficientsam (original size)

    @classmethod
    def load(cls, path: Path, threads: int = 2) -> SamEncoder:
        sess = _session(path, threads)
        inputs = sess.get_inputs()
        if len(inputs) != 1:
            raise InputError(f"a SAM image encoder has one input, this model has {[i.name for i in inputs]}", path)
        inp = inputs[0]
        shape = list(inp.shape)
        outs = sess.get_outputs()
        if not outs:
            raise InputError("the encoder model has no output", path)
        _check_shape(path, outs[0].name, list(outs[0].shape), (1, 256, 64, 64))
        if len(shape) == 3:
            _check_shape(path, inp.name, shape, (None, None, 3))
            return cls(path, sess, inp.name, "hwc", 1024)
        if len(shape) == 4 and inp.name == "batched_images":
            _check_shape(path, inp.name, shape, (1, 3, None, None))
            return cls(path, sess, inp.name, "efficientsam", 0)
        if len(shape) == 4:
            _check_shape(path, inp.name, shape, (1, 3, None, None))
            h, w = _static(shape[2]), _static(shape[3])
            if h is not None and w is not None and h != w:
                raise InputError(f"encoder input {inp.name!r} must be square, got {shape}", path)
            return cls(path, sess, inp.name, "nchw", h or 1024)
        raise InputError(f"unsupported encoder input {inp.name!r} {shape}: expected (h, w, 3) (samexporter "
                         "--use-preprocess), (1, 3, 1024, 1024) or EfficientSAM's batched_images", path)

    def resized_size(self, h: int, w: int) -> tuple[int, int]:
        """(new_h, new_w) after SAM's ResizeLongestSide (identity for EfficientSAM)."""
        if self.kind == "efficientsam":
            return h, w
        scale = self.target / max(h, w)
        return int(h * scale + 0.5), int(w * scale + 0.5)

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """(1, 256, 64, 64) float32 embedding of an (H, W, 3) uint8 RGB image."""
        h, w = image.shape[:2]
        if self.kind == "efficientsam":
            x = image.transpose(2, 0, 1)[None].astype(np.float32) / 255.0
        else:
            nh, nw = self.resized_size(h, w)
            resized = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_LINEAR).astype(np.float32)
            if self.kind == "hwc":
                x = resized
            else:
                x = np.zeros((1, 3, self.target, self.target), np.float32)
                x[0, :, :nh, :nw] = ((resized - PIXEL_MEAN) / PIXEL_STD).transpose(2, 0, 1)
        emb = self.session.run(None, {self.input_name: x})[0]
        return np.asarray(emb, np.float32)


@dataclass
class SamDecoder:
    """A prompt-decoder session (SAM official export or EfficientSAM)."""

    path: Path
    session: object
    kind: str  # "sam" | "efficientsam"
    batch_dynamic: bool
    output_names: list[str]

    @classmethod
    def load(cls, path: Path, threads: int = 2) -> SamDecoder:
        sess = _session(path, threads)
        inputs = {i.name: list(i.shape) for i in sess.get_inputs()}
        outputs = [o.name for o in sess.get_outputs()]
        names = set(inputs)
        if names == SAM_DECODER_INPUTS:
            _check_shape(path, "image_embeddings", inputs["image_embeddings"], (1, 256, 64, 64))
            _check_shape(path, "point_coords", inputs["point_coords"], (None, None, 2))
            _check_shape(path, "point_labels", inputs["point_labels"], (None, None))
            _check_shape(path, "mask_input", inputs["mask_input"], (1, 1, 256, 256))
            _check_shape(path, "has_mask_input", inputs["has_mask_input"], (1,))
            _check_shape(path, "orig_im_size", inputs["orig_im_size"], (2,))
            if "iou_predictions" not in outputs or not ({"low_res_masks", "masks"} & set(outputs)):
                raise InputError(f"SAM decoder outputs {outputs}; expected masks, iou_predictions, low_res_masks",
                                 path)
            return cls(path, sess, "sam", _static(inputs["point_coords"][0]) is None, outputs)
        if names == EFFICIENTSAM_DECODER_INPUTS:
            _check_shape(path, "batched_point_coords", inputs["batched_point_coords"], (1, None, None, 2))
            _check_shape(path, "batched_point_labels", inputs["batched_point_labels"], (1, None, None))
            if len(outputs) < 2:
                raise InputError(f"EfficientSAM decoder outputs {outputs}; expected masks and iou predictions", path)
            return cls(path, sess, "efficientsam", _static(inputs["batched_point_coords"][1]) is None, outputs)
        raise InputError(
            f"decoder inputs {sorted(names)} match neither SAM's ONNX decoder ({sorted(SAM_DECODER_INPUTS)}) "
            f"nor EfficientSAM's ({sorted(EFFICIENTSAM_DECODER_INPUTS)})", path)

    def decode_points(
        self, emb: np.ndarray, points: np.ndarray, orig: tuple[int, int], resized: tuple[int, int]
    ) -> tuple[np.ndarray, np.ndarray, bool]:
        """Single-point prompts (B, 2) in original pixels -> (logits (B, C, h, w), iou (B, C), low_res).

        `low_res` tells whether the logits are SAM's 256x256 padded low-resolution masks (True) or already at
        the original image size (False)."""
        b = len(points)
        if self.kind == "efficientsam":
            coords = points[None, :, None, :].astype(np.float32)
            labels = np.ones((1, b, 1), np.float32)
            feed = {"image_embeddings": emb, "batched_point_coords": coords, "batched_point_labels": labels,
                    "orig_im_size": np.asarray(orig, np.int64)}
            out = self.session.run(None, feed)
            return np.asarray(out[0][0], np.float32), np.asarray(out[1][0], np.float32), False
        sx, sy = resized[1] / orig[1], resized[0] / orig[0]
        coords = np.zeros((b, 2, 2), np.float32)  # the prompt point plus SAM's padding point (label -1)
        coords[:, 0, 0] = points[:, 0] * sx
        coords[:, 0, 1] = points[:, 1] * sy
        labels = np.tile(np.array([[1.0, -1.0]], np.float32), (b, 1))
        feed = {"image_embeddings": emb, "point_coords": coords, "point_labels": labels,
                "mask_input": np.zeros((1, 1, 256, 256), np.float32), "has_mask_input": np.zeros(1, np.float32),
                "orig_im_size": np.asarray(orig, np.float32)}
        out = dict(zip(self.output_names, self.session.run(None, feed)))
        iou = np.asarray(out["iou_predictions"], np.float32)
        if "low_res_masks" in out:
            return np.asarray(out["low_res_masks"], np.float32), iou, True
        return np.asarray(out["masks"], np.float32), iou, False


def stability_score(logits: np.ndarray, offset: float, threshold: float = 0.0) -> np.ndarray:
    """SAM's stability score of (..., h, w) logits: |logits > t + offset| / |logits > t - offset|."""
    inter = (logits > threshold + offset).sum(axis=(-1, -2), dtype=np.int64)
    union = (logits > threshold - offset).sum(axis=(-1, -2), dtype=np.int64)
    return np.where(union > 0, inter / np.maximum(union, 1), 0.0)


def point_grid(points_per_side: int, h: int, w: int) -> np.ndarray:
    """(n^2, 2) prompt points (x, y) in pixels, like SAM's build_point_grid scaled to the image."""
    n = max(1, points_per_side)
    off = 1.0 / (2 * n)
    t = np.linspace(off, 1 - off, n)
    xs, ys = np.meshgrid(t * w, t * h)
    return np.stack([xs.ravel(), ys.ravel()], axis=1)


def mask_nms(masks: MaskSet, scores: np.ndarray, iou_thresh: float) -> np.ndarray:
    """Greedy mask NMS: indices kept, highest score first; a mask overlapping a kept one by IoU > thresh goes."""
    order = np.argsort(-scores, kind="stable")
    if len(order) == 0:
        return order
    iou = mask_iou_matrix(masks, masks)
    keep: list[int] = []
    suppressed = np.zeros(len(order), bool)
    for i in order:
        if suppressed[i]:
            continue
        keep.append(int(i))
        suppressed |= iou[i] > iou_thresh
    return np.asarray(keep, np.int64)


class SamOnnxBackend:
    """Callable backend: image (H, W, 3) uint8 RGB -> MaskSet (overlapping crops, scores = predicted IoU)."""

    def __init__(self, params: SegmentationParams) -> None:
        self.params = params
        files = model_files(params)
        enc, dec = files["sam_encoder"], files["sam_decoder"]
        self.encoder = SamEncoder.load(enc, params.sam_threads)
        self.decoder = SamDecoder.load(dec, params.sam_threads)
        if (self.encoder.kind == "efficientsam") != (self.decoder.kind == "efficientsam"):
            raise InputError(f"encoder {enc.name} ({self.encoder.kind}) and decoder {dec.name} "
                             f"({self.decoder.kind}) are from different model families", dec)

    def __call__(self, image: np.ndarray) -> MaskSet:
        p = self.params
        h, w = image.shape[:2]
        emb = self.encoder(image)
        _check_shape(self.encoder.path, "image_embeddings (produced)", list(emb.shape), (1, 256, 64, 64))
        resized = self.encoder.resized_size(h, w)
        points = point_grid(p.sam_points_per_side, h, w)
        batch = max(1, p.sam_points_per_batch) if self.decoder.batch_dynamic else 1
        if self.decoder.kind == "efficientsam":  # its masks come at full size: bound the memory of one call
            batch = min(batch, 8)
        crops, boxes, scores = [], [], []
        max_area = p.sam_max_area_frac * h * w
        for start in range(0, len(points), batch):
            logits, iou, low_res = self.decoder.decode_points(emb, points[start : start + batch], (h, w), resized)
            if self.decoder.kind == "sam" and logits.shape[1] == 4:
                logits, iou = logits[:, 1:], iou[:, 1:]  # SAM's token 0 is the single-mask output
            logits = logits.reshape(-1, *logits.shape[-2:])
            iou = iou.reshape(-1)
            if low_res:  # the valid (unpadded) part of the 256x256 logits
                vh = int(np.ceil(resized[0] * logits.shape[-2] / self.encoder.target))
                vw = int(np.ceil(resized[1] * logits.shape[-1] / self.encoder.target))
                logits = logits[:, :vh, :vw]
            stab = stability_score(logits, p.sam_stability_score_offset)
            ok = np.flatnonzero((iou >= p.sam_pred_iou_thresh) & (stab >= p.sam_stability_score_thresh))
            for i in ok:
                lg = logits[i]
                full = cv2.resize(lg, (w, h), interpolation=cv2.INTER_LINEAR) if lg.shape != (h, w) else lg
                mask = full > 0.0
                rows = np.flatnonzero(mask.any(axis=1))
                if len(rows) == 0:
                    continue
                cols = np.flatnonzero(mask.any(axis=0))
                x0, x1, y0, y1 = int(cols[0]), int(cols[-1]) + 1, int(rows[0]), int(rows[-1]) + 1
                crop = mask[y0:y1, x0:x1]
                area = int(crop.sum())
                if area < p.min_mask_area_px or area > max_area:
                    continue
                crops.append(crop.copy())
                boxes.append((x0, y0, x1, y1))
                scores.append(float(iou[i]))
        if not crops:
            return MaskSet.empty((h, w))
        cand = MaskSet((h, w), np.asarray(scores, np.float32), boxes=np.asarray(boxes, np.int32), crops=crops)
        keep = mask_nms(cand, cand.scores, p.sam_box_nms_thresh)
        log.debug("sam-onnx: %d prompts, %d candidates, %d after NMS", len(points), len(cand), len(keep))
        return cand.subset(np.sort(keep))


def make(params: SegmentationParams) -> Backend:
    """Backend factory for the registry (loads and validates both models now, so errors surface early)."""
    return SamOnnxBackend(params)
