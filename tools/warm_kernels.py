"""Compile the search kernels into numba's on-disk cache ahead of the first match (`make install` runs this).
It lives outside the association package on purpose: `kernel_cache` keys the cache on that package's sources.

    python -m sosmatch.tools.warm_kernels

The first search after an install otherwise compiles them on the spot: minutes of CPU before a match that then
takes seconds (BENCHMARKS.md, "The new-user sweep"). Here two small synthetic maps are matched the ways `sosmatch
match` searches (the default search on maps in their own frames, with a position prior as for two maps in one
EPSG, and the paper preset), so every kernel is compiled for the argument types the searches call it with. A
cache that is already complete makes this a no-op of a second; a failure never breaks the install (the first
match then compiles, with `kernel_cache.announce_compile`'s notice).
"""

from __future__ import annotations

import dataclasses
import logging
import sys
import time

import numpy as np

from ..plugin.association import kernel_cache

log = logging.getLogger(__name__)


def warm_kernels() -> tuple[int, int, float]:
    """Compile the searches' kernels and mark them compiled; returns (kernels without a cache entry before, after,
    CPU seconds). Another process compiling meanwhile is waited for kernel by kernel (`kernel_cache.CompileLock`):
    what it compiled is loaded here, not compiled again."""
    from ..plugin.association import associate
    from ..plugin.association.synthetic import survey_map_pair
    from ..plugin.match_answer import match_maps
    from ..plugin.params import Params, preset_params

    before = len(kernel_cache.uncompiled_kernels())
    t0 = time.process_time()
    if before:  # some kernels never get an entry of their own (`kernel_cache.uncompiled_kernels`)
        pair = survey_map_pair(120, seed=1)
        default = Params()
        prior = dataclasses.replace(default, association=dataclasses.replace(default.association,
                                                                             position_prior_m=20.0))
        for params, common in ((default, False), (prior, True), (preset_params("paper"), False)):
            match_maps(pair.points_a, pair.sizes_a, pair.points_b, pair.sizes_b, params, common_frame=common)
        # the straightforward reference search (`match --exhaustive`) and the one-problem API (`associate`)
        match_maps(pair.points_a, pair.sizes_a, pair.points_b, pair.sizes_b, default, common_frame=False,
                   exhaustive=True)
        truth = pair.truth[:40]
        for serial in (True, False):  # one problem is built on one thread, or on both from 256 associations
            pairs = truth if serial else np.concatenate([truth, _wrong_pairs(len(pair.points_a), len(pair.points_b),
                                                                             600)])
            associate(pair.points_a, pair.points_b, pairs)
    kernel_cache.mark_compiled()
    return before, len(kernel_cache.uncompiled_kernels()), time.process_time() - t0


def _wrong_pairs(n_a: int, n_b: int, m: int) -> np.ndarray:
    """m associations drawn at random (fixed seed): a problem large enough for the threaded graph build."""
    rng = np.random.default_rng(0)
    return np.stack([rng.integers(0, n_a, m), rng.integers(0, n_b, m)], 1).astype(np.int64)


def main(argv: list[str] | None = None) -> int:
    import argparse

    argparse.ArgumentParser(prog="python -m sosmatch.tools.warm_kernels",
                            description="Compile the search kernels into numba's on-disk cache ahead of the first "
                                        "match (make install runs this); a no-op when they are cached already."
                            ).parse_args(argv)
    total, missing = len(kernel_cache.kernels()), len(kernel_cache.uncompiled_kernels())
    if kernel_cache.compiled_for_these_sources() or not missing:
        print(f"sosmatch: the search kernels are compiled already ({total - missing} of {total} cached)", flush=True)
        return 0
    print(f"sosmatch: {kernel_cache.compile_message(missing, total)}", flush=True)
    try:
        before, after, cpu = warm_kernels()
    except Exception as error:  # noqa: BLE001 - an install never fails on this: the first match compiles instead
        print(f"sosmatch: kernels not compiled ahead ({error}); the first match compiles them", file=sys.stderr)
        return 0
    print(f"sosmatch: {before - after} kernels compiled in {cpu:.0f} s of CPU"
          + (f" ({after} others are compiled into their callers, or on a path of their own)" if after else ""),
          flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
