"""The model files a run's segmentation backend reads (`plugin.segmentation.model_files`), resolved once per run
and fingerprinted by their contents.

A backend such as `sam-onnx` takes its models from settings that may be empty (the environment names the files
then) or name a path whose file may be replaced: the settings alone do not say which model made an output. So an
output's identity and its caches are keyed by the files' sha256 (what the model is), and its record names the
files (path, size, sha256). A model named by the environment may move or be copied and stays the same model; one
named by a setting (`segmentation.sam_encoder=PATH`) is also keyed by that setting, as every setting is, so the
same model at another configured path is another output (`--overwrite`). A backend without
model files (`classical`) adds nothing: its outputs' identities and cache keys are those of earlier versions.
Cost: sha256 streams at ~1.9 GB/s of CPU here, ~0.2 s for a 400 MB ViT-B encoder, once per run (BENCHMARKS
"SAM model files in a run's identity").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..plugin.errors import InputError
from ..plugin.params import SegmentationParams
from ..plugin.segmentation import model_files, with_model_files
from .output_markers import VersionedIdentity, sha256_file

#: why an output an earlier version made with a backend's model files is refused (not known which model made it)
UNRECORDED = ("one made before sosmatch keyed outputs by the segmentation's model files (fix98): which model made "
              "it is not known")


@dataclass(frozen=True)
class SegmentationModels:
    """The model files of one run's segmentation: setting -> absolute path, their sizes and sha256."""

    files: dict[str, Path] = field(default_factory=dict)
    sizes: dict[str, int] = field(default_factory=dict)
    sha256: dict[str, str] = field(default_factory=dict)

    def identity(self) -> dict[str, str]:
        """What an output's identity and cache key hold of them: setting -> sha256 ({} for none)."""
        return dict(self.sha256)

    def record(self) -> dict[str, dict[str, Any]] | None:
        """What a run's record says of them: setting -> {path, bytes, sha256}; None for a backend without any."""
        if not self.files:
            return None
        return {name: {"path": str(path), "bytes": self.sizes[name], "sha256": self.sha256[name]}
                for name, path in self.files.items()}

    def params(self, seg: SegmentationParams) -> SegmentationParams:
        """`seg` naming these files, for building the backend (`plugin.segmentation.with_model_files`): the run
        segments with the files it fingerprinted, whatever the environment says later."""
        return with_model_files(seg, self.files)


def segmentation_models(seg: SegmentationParams) -> SegmentationModels:
    """The model files `seg`'s backend reads (resolved from the settings or the environment now) with their sizes
    and contents' sha256. InputError (naming the file) for a missing or unreadable one."""
    files = model_files(seg)
    sizes, digests = {}, {}
    for name, path in files.items():
        try:
            sizes[name] = path.stat().st_size
            digests[name] = sha256_file(path)
        except OSError as exc:
            raise InputError(f"cannot read the model file ({exc.strerror or exc})", path) from None
    return SegmentationModels(files, sizes, digests)


def keyed_by_models(identity: Callable[[dict[str, Any]], VersionedIdentity],
                    models: SegmentationModels) -> VersionedIdentity:
    """An output's identity with its segmentation's model files: `identity(extra)` builds it with `extra` added to
    its envelope, {"models": setting -> sha256} for a backend with model files, {} (the identity of earlier
    versions, unchanged) for one without. Outputs earlier versions made with model files are refused as another
    output, the refusal saying why (`UNRECORDED`)."""
    if not models.sha256:
        return identity({})
    today, before = identity({"models": models.identity()}), identity({})
    unknown = tuple((i, UNRECORDED) for i in (before.today, *before.same_as))
    return VersionedIdentity(today.today, today.same_as, (*today.otherwise, *unknown))
