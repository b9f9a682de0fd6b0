"""`sam-onnx` with tiny ONNX models built here (same input/output names and shapes as SAM's exports).

The fake decoder answers a point prompt with concentric discs around the point (in SAM's 1024 frame), so the
real preprocessing, coordinate transforms, batching, filtering, upsampling and NMS all run and can be checked.
"""

import json
from dataclasses import replace

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from sosmatch.database.output_markers import sha256_file
from sosmatch.plugin.errors import InputError
from sosmatch.plugin.params import SegmentationParams
from sosmatch.plugin.segmentation import MaskSet, get_backend
from sosmatch.plugin.segmentation.sam_onnx import mask_nms, point_grid, stability_score

OPSET = [helper.make_opsetid("", 17)]
# channel 0 = single-mask token (dropped), 1: r=40 sharp, 2: r=80 sharp, 3: r=200 but unstable (soft logits)
RADII = np.array([60.0, 40.0, 80.0, 200.0], np.float32)
SLOPES = np.array([100.0, 100.0, 100.0, 0.5], np.float32)  # stability (1-1/s)/(1+1/s)
IOUS = np.array([0.99, 0.95, 0.80, 0.97], np.float32)


def _const(name, array):
    return helper.make_node("Constant", [], [name], value=numpy_helper.from_array(np.asarray(array), name + "_v"))


def _save(graph, path):
    model = helper.make_model(graph, opset_imports=OPSET)
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def make_encoder(path, kind="hwc", out_channels=256):
    if kind == "hwc":
        inp = helper.make_tensor_value_info("input_image", TensorProto.FLOAT, ["h", "w", 3])
    elif kind == "nchw":
        inp = helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, 1024, 1024])
    else:
        inp = helper.make_tensor_value_info("batched_images", TensorProto.FLOAT, [1, 3, "H", "W"])
    out = helper.make_tensor_value_info("image_embeddings", TensorProto.FLOAT, [1, out_channels, 64, 64])
    nodes = [
        helper.make_node("ReduceMean", [inp.name], ["m"], keepdims=0),
        _const("shape", np.array([1, out_channels, 64, 64], np.int64)),
        helper.make_node("Expand", ["m", "shape"], ["image_embeddings"]),
    ]
    return _save(helper.make_graph(nodes, "enc", [inp], [out]), path)


def make_decoder(path, batch="B", mask_size=256, names=None, with_low_res=True):
    f = TensorProto.FLOAT
    inputs = [
        helper.make_tensor_value_info("image_embeddings", f, [1, 256, 64, 64]),
        helper.make_tensor_value_info("point_coords", f, [batch, "N", 2]),
        helper.make_tensor_value_info("point_labels", f, [batch, "N"]),
        helper.make_tensor_value_info("mask_input", f, [1, 1, mask_size, mask_size]),
        helper.make_tensor_value_info("has_mask_input", f, [1]),
        helper.make_tensor_value_info("orig_im_size", f, [2]),
    ]
    if names:
        for vi, name in zip(inputs, names):
            vi.name = name
    n = [i.name for i in inputs]
    grid = (np.arange(256, dtype=np.float32) + 0.5) * 4.0
    nodes = [
        _const("gx", grid[None, None, None, :]),
        _const("gy", grid[None, None, :, None]),
        _const("r2", (RADII**2)[None, :, None, None]),
        _const("slope", SLOPES[None, :, None, None]),
        _const("iou0", IOUS[None, :]),
        _const("zero", np.array(0.0, np.float32)),
        _const("s0", np.array([0, 0], np.int64)), _const("e1", np.array([1, 1], np.int64)),
        _const("s1", np.array([0, 1], np.int64)), _const("e2", np.array([1, 2], np.int64)),
        _const("ax", np.array([1, 2], np.int64)), _const("ax3", np.array([3], np.int64)),
        helper.make_node("Slice", [n[1], "s0", "e1", "ax"], ["px3"]),
        helper.make_node("Slice", [n[1], "s1", "e2", "ax"], ["py3"]),
        helper.make_node("Unsqueeze", ["px3", "ax3"], ["px"]),
        helper.make_node("Unsqueeze", ["py3", "ax3"], ["py"]),
        helper.make_node("Sub", ["gx", "px"], ["dx"]),
        helper.make_node("Sub", ["gy", "py"], ["dy"]),
        helper.make_node("Mul", ["dx", "dx"], ["dx2"]),
        helper.make_node("Mul", ["dy", "dy"], ["dy2"]),
        helper.make_node("Add", ["dx2", "dy2"], ["d2"]),
        helper.make_node("Sub", ["r2", "d2"], ["inside"]),
        helper.make_node("Div", ["inside", "r2"], ["rel"]),
        helper.make_node("Mul", ["rel", "slope"], ["low_res_masks"]),
    ]
    # every other input takes part (times zero), so the graph really consumes what it declares
    nodes += [
        _const("ax12", np.array([1, 2], np.int64)),
        helper.make_node("ReduceSum", [n[1], "ax12"], ["b3"], keepdims=1),  # (B, 1, 1)
        _const("shape_b1", np.array([-1, 1], np.int64)),
        helper.make_node("Reshape", ["b3", "shape_b1"], ["b1"]),  # (B, 1)
        helper.make_node("ReduceSum", [n[0]], ["e_s"], keepdims=0),
        helper.make_node("ReduceSum", [n[2]], ["l_s"], keepdims=0),
        helper.make_node("ReduceSum", [n[3]], ["m_s"], keepdims=0),
        helper.make_node("ReduceSum", [n[4]], ["h_s"], keepdims=0),
        helper.make_node("ReduceSum", [n[5]], ["o_s"], keepdims=0),
        helper.make_node("Sum", ["e_s", "l_s", "m_s", "h_s", "o_s"], ["all_s"]),
        helper.make_node("Add", ["b1", "all_s"], ["tot"]),
        helper.make_node("Mul", ["tot", "zero"], ["z"]),
        helper.make_node("Add", ["iou0", "z"], ["iou_predictions"]),
        helper.make_node("Identity", ["low_res_masks"], ["masks"]),
    ]
    outputs = [helper.make_tensor_value_info("masks", f, [batch, 4, None, None]),
               helper.make_tensor_value_info("iou_predictions", f, [batch, 4])]
    if with_low_res:
        outputs.append(helper.make_tensor_value_info("low_res_masks", f, [batch, 4, 256, 256]))
    return _save(helper.make_graph(nodes, "dec", inputs, outputs), path)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    d = tmp_path_factory.mktemp("sam")
    return {
        "enc_hwc": make_encoder(d / "enc_hwc.onnx", "hwc"),
        "enc_nchw": make_encoder(d / "enc_nchw.onnx", "nchw"),
        "dec": make_decoder(d / "dec.onnx"),
        "dec_b1": make_decoder(d / "dec_b1.onnx", batch=1),
        "bad_names": make_decoder(d / "bad_names.onnx", names=["image_embeddings", "coords"]),
        "bad_shape": make_decoder(d / "bad_shape.onnx", mask_size=128),
        "enc_bad": make_encoder(d / "enc_bad.onnx", "hwc", out_channels=128),
        "dir": d,
    }


def _params(models, enc="enc_hwc", dec="dec", **kw):
    kw.setdefault("sam_points_per_side", 4)
    return SegmentationParams(backend="sam-onnx", sam_encoder=str(models[enc]), sam_decoder=str(models[dec]), **kw)


def _expected_discs(h, w, pps, radius_1024):
    pts = point_grid(pps, h, w)
    r = radius_1024 * max(h, w) / 1024.0
    return pts, r


@pytest.mark.parametrize("enc", ["enc_hwc", "enc_nchw"])
def test_segment_everything_recovers_discs_in_original_pixels(models, enc):
    h, w = 300, 400  # not square: exercises resize, the padded low-res crop and the upsampling
    image = np.random.default_rng(0).integers(0, 255, (h, w, 3), dtype=np.uint8)
    backend = get_backend("sam-onnx", _params(models, enc))
    masks = backend(image)
    assert masks.overlapping
    pts, r = _expected_discs(h, w, 4, 40.0)
    # channel 2 (iou 0.80 < 0.86) and channel 3 (unstable) are filtered; channel 0 is the single-mask token
    assert len(masks) == len(pts)
    assert np.allclose(masks.scores, 0.95)
    areas = masks.areas()
    assert np.allclose(areas, np.pi * r * r, rtol=0.12)
    boxes = masks.bboxes
    centers = np.stack([(boxes[:, 0] + boxes[:, 2]) / 2, (boxes[:, 1] + boxes[:, 3]) / 2], 1)
    d = np.linalg.norm(centers[:, None] - pts[None], axis=2)
    assert np.all(d.min(axis=1) < 2.0) and len(set(d.argmin(axis=1))) == len(pts)


def test_filters_batching_and_nms(models):
    h, w = 240, 320
    image = np.full((h, w, 3), 90, np.uint8)
    loose = get_backend("sam-onnx", _params(models, sam_pred_iou_thresh=0.75))(image)
    assert len(loose) == 2 * 16  # r=40 and r=80 discs at every grid point (concentric IoU 0.25 < 0.7)
    pts, r80 = _expected_discs(h, w, 4, 80.0)
    assert np.isclose(loose.areas().max(), np.pi * r80 * r80, rtol=0.12)
    unbatched = get_backend("sam-onnx", _params(models, dec="dec_b1", sam_pred_iou_thresh=0.75))(image)
    assert np.array_equal(unbatched.rasterise(), loose.rasterise())
    assert np.array_equal(unbatched.scores, loose.scores)
    strict_nms = get_backend("sam-onnx", _params(models, sam_pred_iou_thresh=0.75, sam_box_nms_thresh=0.2))(image)
    assert len(strict_nms) == 16 and np.allclose(strict_nms.scores, 0.95)  # r=80 discs suppressed by r=40
    big = get_backend("sam-onnx", _params(models, sam_pred_iou_thresh=0.75, sam_max_area_frac=0.02))(image)
    assert len(big) == 16  # r=80 discs are 2.6 % of the image, r=40 ones 0.6 %


def test_mask_nms_and_stability_helpers():
    a = np.zeros((50, 50), bool)
    a[10:30, 10:30] = True
    b = np.zeros((50, 50), bool)
    b[11:31, 10:30] = True
    c = np.zeros((50, 50), bool)
    c[35:45, 35:45] = True
    ms = MaskSet.from_masks([a, b, c], scores=[0.8, 0.9, 0.7])
    assert mask_nms(ms, ms.scores, 0.7).tolist() == [1, 2]
    logits = np.stack([np.full((8, 8), 5.0), np.linspace(-2, 2, 64).reshape(8, 8)])
    s = stability_score(logits, 1.0)
    assert s[0] == 1.0 and 0.2 < s[1] < 0.5


def test_model_errors_name_the_file(models, monkeypatch):
    monkeypatch.delenv("SOSMATCH_SAM_ENCODER", raising=False)
    monkeypatch.delenv("SOSMATCH_SAM_DECODER", raising=False)
    with pytest.raises(InputError, match="SOSMATCH_SAM_ENCODER"):
        get_backend("sam-onnx", SegmentationParams())
    missing = models["dir"] / "nope.onnx"
    with pytest.raises(InputError, match="nope.onnx.*not found"):
        get_backend("sam-onnx", SegmentationParams(sam_encoder=str(missing), sam_decoder=str(models["dec"])))
    with pytest.raises(InputError, match="bad_names.onnx.*match neither"):
        get_backend("sam-onnx", _params(models, dec="bad_names"))
    with pytest.raises(InputError, match="bad_shape.onnx.*mask_input"):
        get_backend("sam-onnx", _params(models, dec="bad_shape"))
    with pytest.raises(InputError, match="enc_bad.onnx.*image_embeddings"):
        get_backend("sam-onnx", _params(models, enc="enc_bad"))
    junk = models["dir"] / "junk.onnx"
    junk.write_bytes(b"this is not a protobuf")
    with pytest.raises(InputError, match="junk.onnx.*not a loadable ONNX"):
        get_backend("sam-onnx", SegmentationParams(sam_encoder=str(junk), sam_decoder=str(models["dec"])))
    # the environment variables are honoured
    monkeypatch.setenv("SOSMATCH_SAM_ENCODER", str(models["enc_hwc"]))
    monkeypatch.setenv("SOSMATCH_SAM_DECODER", str(models["dec"]))
    masks = get_backend("sam-onnx", SegmentationParams(sam_points_per_side=2))(np.zeros((64, 64, 3), np.uint8))
    assert len(masks) == 4


def make_efficientsam_decoder(path):
    """EfficientSAM-style decoder: masks (1, Q, 3, H, W) at the original size, IoU (1, Q, 3), pixel coordinates."""
    f = TensorProto.FLOAT
    inputs = [
        helper.make_tensor_value_info("image_embeddings", f, [1, 256, 64, 64]),
        helper.make_tensor_value_info("batched_point_coords", f, [1, "Q", "N", 2]),
        helper.make_tensor_value_info("batched_point_labels", f, [1, "Q", "N"]),
        helper.make_tensor_value_info("orig_im_size", TensorProto.INT64, [2]),
    ]
    radii = np.array([10.0, 20.0, 40.0], np.float32)
    nodes = [
        _const("i0", np.array([0], np.int64)), _const("i1", np.array([1], np.int64)),
        _const("half", np.array(0.5, np.float32)), _const("one", np.array(1.0, np.float32)),
        helper.make_node("Gather", ["orig_im_size", "i0"], ["h64"]),
        helper.make_node("Gather", ["orig_im_size", "i1"], ["w64"]),
        helper.make_node("Cast", ["h64"], ["hf1"], to=TensorProto.FLOAT),
        helper.make_node("Cast", ["w64"], ["wf1"], to=TensorProto.FLOAT),
        _const("scalar", np.zeros(0, np.int64)),
        helper.make_node("Reshape", ["hf1", "scalar"], ["hf"]),
        helper.make_node("Reshape", ["wf1", "scalar"], ["wf"]),
        helper.make_node("Range", ["half", "hf", "one"], ["ys"]),
        helper.make_node("Range", ["half", "wf", "one"], ["xs"]),
        _const("shx", np.array([1, 1, 1, 1, -1], np.int64)), _const("shy", np.array([1, 1, 1, -1, 1], np.int64)),
        helper.make_node("Reshape", ["xs", "shx"], ["gx"]),
        helper.make_node("Reshape", ["ys", "shy"], ["gy"]),
        # point (1, Q, 1, 2) -> px, py (1, Q, 1, 1, 1)
        _const("s0", np.array([0], np.int64)), _const("e1", np.array([1], np.int64)),
        _const("e2", np.array([2], np.int64)), _const("ax3", np.array([3], np.int64)),
        helper.make_node("Slice", ["batched_point_coords", "s0", "e1", "ax3"], ["px4"]),
        helper.make_node("Slice", ["batched_point_coords", "e1", "e2", "ax3"], ["py4"]),
        _const("sh5", np.array([1, -1, 1, 1, 1], np.int64)),
        helper.make_node("Reshape", ["px4", "sh5"], ["px"]),
        helper.make_node("Reshape", ["py4", "sh5"], ["py"]),
        helper.make_node("Sub", ["gx", "px"], ["dx"]), helper.make_node("Sub", ["gy", "py"], ["dy"]),
        helper.make_node("Mul", ["dx", "dx"], ["dx2"]), helper.make_node("Mul", ["dy", "dy"], ["dy2"]),
        helper.make_node("Add", ["dx2", "dy2"], ["d2"]),
        _const("r2", (radii**2)[None, None, :, None, None]),
        helper.make_node("Sub", ["r2", "d2"], ["inside"]),
        helper.make_node("Div", ["inside", "r2"], ["rel"]),
        _const("slope", np.array(100.0, np.float32)),
        helper.make_node("Mul", ["rel", "slope"], ["output_masks"]),
        # IoU (1, Q, 3): constants, tied to the inputs by a zero factor
        _const("iou0", np.array([[[0.9, 0.95, 0.7]]], np.float32)),
        _const("ax23", np.array([2, 3], np.int64)),
        helper.make_node("ReduceSum", ["batched_point_coords", "ax23"], ["q_s"], keepdims=0),  # (1, Q)
        helper.make_node("ReduceSum", ["batched_point_labels"], ["l_s"], keepdims=0),
        helper.make_node("ReduceSum", ["image_embeddings"], ["e_s"], keepdims=0),
        helper.make_node("Add", ["l_s", "e_s"], ["le"]),
        helper.make_node("Add", ["q_s", "le"], ["qle"]),
        _const("sh13", np.array([1, -1, 1], np.int64)),
        helper.make_node("Reshape", ["qle", "sh13"], ["q3"]),
        _const("zero", np.array(0.0, np.float32)),
        helper.make_node("Mul", ["q3", "zero"], ["z"]),
        helper.make_node("Add", ["iou0", "z"], ["iou_predictions"]),
    ]
    outputs = [helper.make_tensor_value_info("output_masks", f, [1, "Q", 3, None, None]),
               helper.make_tensor_value_info("iou_predictions", f, [1, "Q", 3])]
    return _save(helper.make_graph(nodes, "effsam_dec", inputs, outputs), path)


def test_efficientsam_variant(models):
    enc = make_encoder(models["dir"] / "effsam_enc.onnx", "efficientsam")
    dec = make_efficientsam_decoder(models["dir"] / "effsam_dec.onnx")
    params = SegmentationParams(sam_encoder=str(enc), sam_decoder=str(dec), sam_points_per_side=3)
    h, w = 150, 210
    masks = get_backend("sam-onnx", params)(np.zeros((h, w, 3), np.uint8))
    # candidates r=10 (iou 0.9) and r=20 (0.95) pass, r=40 (0.7) fails; coordinates are original pixels
    assert len(masks) == 18
    assert sorted(set(np.round(masks.scores, 2))) == [0.9, 0.95]
    pts = point_grid(3, h, w)
    big = masks.subset(np.flatnonzero(np.isclose(masks.scores, 0.95)))
    assert np.allclose(np.sort(big.areas()), np.pi * 400, rtol=0.05)
    centers = np.stack([(big.bboxes[:, 0] + big.bboxes[:, 2]) / 2, (big.bboxes[:, 1] + big.bboxes[:, 3]) / 2], 1)
    assert np.linalg.norm(centers[:, None] - pts[None], axis=2).min(axis=1).max() < 1.5
    # an EfficientSAM encoder with SAM's decoder is refused
    with pytest.raises(InputError, match="different model families"):
        get_backend("sam-onnx", SegmentationParams(sam_encoder=str(enc), sam_decoder=str(models["dec"])))


# -- which model made an output: the files' contents are part of its identity and cache keys ----------------------

def _other_model(path, out):
    """The model at `path` saved again with another doc string: same behaviour, other contents."""
    model = onnx.load(str(path))
    model.doc_string = f"another model: {out.name}"
    onnx.save(model, str(out))
    return out


def _from_environment(monkeypatch, models, enc):
    monkeypatch.setenv("SOSMATCH_SAM_ENCODER", str(enc))
    monkeypatch.setenv("SOSMATCH_SAM_DECODER", str(models["dec"]))


def _images(folder, n=2, size=(96, 128)):
    import cv2

    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(n):
        cv2.imwrite(str(folder / f"frame_{i:05d}.png"), rng.integers(0, 255, (*size, 3), dtype=np.uint8))
    return folder


def test_segment_with_another_model_from_the_environment_is_another_output(models, tmp_path, monkeypatch):
    from sosmatch.plugin.params import Params
    from sosmatch.workflows import segment

    images = _images(tmp_path / "frames")
    params = Params(segmentation=SegmentationParams(backend="sam-onnx", sam_points_per_side=4))
    _from_environment(monkeypatch, models, models["enc_hwc"])
    segment.run([images], tmp_path / "seg", params)
    record = json.loads((tmp_path / "seg" / "frame_00000.png.json").read_text())["models"]
    assert record["sam_encoder"]["path"] == str(models["enc_hwc"].resolve())
    assert record["sam_encoder"]["sha256"] == sha256_file(models["enc_hwc"])
    segment.run([images], tmp_path / "seg", params)  # the same model: the same output, run again
    _from_environment(monkeypatch, models, _other_model(models["enc_hwc"], tmp_path / "other.onnx"))
    with pytest.raises(InputError, match="other inputs or settings"):
        segment.run([images], tmp_path / "seg", params)
    segment.run([images], tmp_path / "seg", params, overwrite=True)
    record = json.loads((tmp_path / "seg" / "frame_00000.png.json").read_text())["models"]
    assert record["sam_encoder"]["path"] == str((tmp_path / "other.onnx").resolve())


def test_segment_notices_a_model_replaced_at_its_configured_path(models, tmp_path):
    from sosmatch.plugin.params import Params
    from sosmatch.workflows import segment

    images = _images(tmp_path / "frames")
    enc = tmp_path / "enc.onnx"
    enc.write_bytes(models["enc_hwc"].read_bytes())
    params = Params(segmentation=replace(_params(models), sam_encoder=str(enc)))
    segment.run([images], tmp_path / "seg", params)
    _other_model(models["enc_hwc"], enc)
    with pytest.raises(InputError, match="other inputs or settings"):
        segment.run([images], tmp_path / "seg", params)


def test_classical_identity_and_cache_key_hold_no_models(monkeypatch):
    from sosmatch.database.segmentation_models import segmentation_models

    monkeypatch.setenv("SOSMATCH_SAM_ENCODER", "/nonexistent.onnx")  # read by sam-onnx only
    models = segmentation_models(SegmentationParams())
    assert models.identity() == {} and models.record() is None
    assert models.params(SegmentationParams()) == SegmentationParams()


def _session(root, n=8):
    """A straight flight (2 m steps) over noise images: enough for keyframes, tracks are not the point here."""
    from sosmatch.database.cameras import write_cameras_txt
    from sosmatch.database.poses import write_poses_csv
    from sosmatch.plugin.geometry import Camera, Poses

    images = _images(root / "images", n, (96, 128))
    names = sorted(p.name for p in images.iterdir())
    centers = np.stack([np.arange(n) * 2.0, np.zeros(n), np.full(n, 60.0)], 1)
    write_poses_csv(root / "poses.csv", Poses(names, np.repeat(np.diag([1.0, -1.0, -1.0])[None], n, 0), centers))
    write_cameras_txt(root / "cameras.txt", {1: Camera(128, 96, 100.0, 100.0, 64.0, 48.0)})
    return root


def test_map_with_another_model_is_another_map_and_reuses_no_cached_masks(models, tmp_path, monkeypatch):
    from sosmatch.plugin.params import Params, with_overrides
    from sosmatch.workflows import map as map_workflow

    root = _session(tmp_path / "s")
    inputs = map_workflow.load_inputs(root / "images", root / "poses.csv", root / "cameras.txt")
    params = with_overrides(Params(), {"segmentation.backend": "sam-onnx", "segmentation.sam_points_per_side": 4,
                                       "quality.refuse": False, "pose_check.enabled": False})
    other = _other_model(models["enc_hwc"], tmp_path / "other.onnx")

    class Stop(Exception):
        pass

    def stop_at_2(k):
        if k == 2:
            raise Stop

    _from_environment(monkeypatch, models, models["enc_hwc"])
    out = tmp_path / "map"
    with pytest.raises(Stop):  # interrupted, its cache kept in .partial
        map_workflow.run(params, inputs, out, progress=False, on_keyframe=stop_at_2)
    _from_environment(monkeypatch, models, other)
    summary = map_workflow.run(params, inputs, out, progress=False)
    assert summary.keyframes_from_cache == 0  # masks of the first model are not this map's
    record = json.loads((out / "run.json").read_text())["segmentation_models"]
    assert record["sam_encoder"] == {"path": str(other.resolve()), "bytes": other.stat().st_size,
                                     "sha256": sha256_file(other)}
    assert record["sam_decoder"]["sha256"] == sha256_file(models["dec"])
    _from_environment(monkeypatch, models, models["enc_hwc"])  # the same command with the first model
    with pytest.raises(InputError, match="other inputs or settings"):
        map_workflow.run(params, inputs, out, progress=False)
    assert json.loads((out / "run.json").read_text())["segmentation_models"] == {**record}


def test_a_batch_with_another_model_is_another_batch_and_maps_again(models, tmp_path, monkeypatch):
    from sosmatch.plugin.params import Params, with_overrides
    from sosmatch.workflows import batch
    from sosmatch.workflows.executors import LocalExecutor

    _session(tmp_path / "flights" / "F")
    params = with_overrides(Params(), {"segmentation.backend": "sam-onnx", "segmentation.sam_points_per_side": 4,
                                       "quality.refuse": False, "pose_check.enabled": False})
    options = batch.BatchOptions(progress=False, merge=False, changes=False)
    out = tmp_path / "out"
    _from_environment(monkeypatch, models, models["enc_hwc"])
    batch.run(tmp_path / "flights", out, params, executor=LocalExecutor(0), options=options)
    other = _other_model(models["enc_hwc"], tmp_path / "other.onnx")
    _from_environment(monkeypatch, models, other)
    with pytest.raises(InputError, match="other inputs or settings"):
        batch.run(tmp_path / "flights", out, params, executor=LocalExecutor(0), options=options)
    again = batch.run(tmp_path / "flights", out, params, executor=LocalExecutor(0),
                      options=batch.BatchOptions(progress=False, merge=False, changes=False, overwrite=True))
    assert not again.sessions[0].get("resumed")  # mapped again, with the other model
    record = json.loads((out / "sessions" / "F" / "run.json").read_text())["segmentation_models"]
    assert record["sam_encoder"]["sha256"] == sha256_file(other)
