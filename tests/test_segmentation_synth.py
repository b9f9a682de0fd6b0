"""The `classical` backend on a tiny session of the synthetic world (`sosmatch synth`), scored like the benchmark."""

import numpy as np
import pytest

from sosmatch.plugin.params import SegmentationParams
from sosmatch.tools.benchmarks.bench_segment import evaluate_session
from sosmatch.tools.cli import main


@pytest.fixture(scope="module")
def tiny_session(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth") / "summer"
    code = main(["synth", "--out", str(out), "--season", "summer", "--frames", "3", "--world-size", "200", "-q"])
    assert code == 0
    return out


def test_classical_finds_most_synthetic_objects(tiny_session):
    q = evaluate_session(tiny_session, SegmentationParams(), 0)
    assert q["frames"] == 3 and q["objects"] >= 10
    # the bar is 0.8 on full sessions; a 3-frame world is noisy, so this only guards against regressions
    assert q["recall"] >= 0.6, q
    assert 0 < q["masks_per_frame"] < 400
    # conifers (dark, compact) are the easiest kind: nearly all must be found
    found, total = q["per_kind"].get("conifer", (0, 0))
    assert total == 0 or found / total >= 0.7


def test_no_object_no_mask_is_not_an_error(tiny_session):
    q = evaluate_session(tiny_session, SegmentationParams(classical_min_contrast=1e9), 1)
    assert q["masks_per_frame"] == 0 and q["recall"] == 0.0 and np.isfinite(q["median_s"])
