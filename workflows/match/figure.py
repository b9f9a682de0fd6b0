"""match.png: both maps in A's frame, the answer's associations drawn."""

from __future__ import annotations

import io

import numpy as np

from .result import MatchResult


def alignment_png(result: MatchResult) -> bytes:
    """Both maps in A's frame (top view), associations as segments, the best hypothesis highlighted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    a, b = result.map_a.lmap.positions, result.map_b.lmap.positions
    s = result.search
    transform = result.transform
    fig, ax = plt.subplots(figsize=(8, 8), dpi=100)
    ax.scatter(a[:, 0], a[:, 1], s=6, c="#1f77b4", label=f"map A ({len(a)})", linewidths=0)
    if transform is not None:
        bt = transform.apply(b)
        ax.scatter(bt[:, 0], bt[:, 1], s=6, c="#ff7f0e", label=f"map B in A's frame ({len(b)})", linewidths=0)
        assoc = result.associations
        segs = np.stack([a[assoc[:, 0], :2], bt[assoc[:, 1], :2]], axis=1)
        ax.add_collection(LineCollection(segs, colors="#2ca02c", linewidths=1.0))
        # at map scale the segments are sub-metre: mark the associated landmarks too
        ax.scatter(a[assoc[:, 0], 0], a[assoc[:, 0], 1], s=14, marker="+", c="#2ca02c", linewidths=0.8,
                   label=f"consensus associations ({len(assoc)})")
        if s.best is not None:
            best = s.hypotheses[s.best]
            ax.scatter(a[best.associations[:, 0], 0], a[best.associations[:, 0], 1], s=40, facecolors="none",
                       edgecolors="#d62728", linewidths=1.2, label=f"best hypothesis |S|={best.size}")
        title = f"{len(s.accepted)} accepted of {len(s.hypotheses)} solved window pairs"
        if result.answer is not None and result.answer.verification is not None:
            title += ", verified" if result.accepted else ", verification refused it"
    else:
        ax.scatter(b[:, 0], b[:, 1], s=6, c="#ff7f0e", label=f"map B, own frame ({len(b)})", linewidths=0)
        title = "no accepted hypothesis (map B shown in its own frame)"
    ax.set_title(title)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="upper right", fontsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()
