"""Multi-session geometry and graph algorithms (pure numpy): similarity transforms, Umeyama alignment,
the session graph (connected groups, spanning-tree transforms into one reference frame), landmark fusion groups
and nearest-session pairs.

Transform convention: a `Sim3` maps points of a *source* frame into a *target* frame, x_t = s R x_s + t.
For a session pair (A, B) the stored transform is `a_from_b` (B's landmarks into A's frame), as in match.json.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .association.gates import size_ratio
from .geometry import rotation_angle_deg


@dataclass(frozen=True)
class Sim3:
    """A similarity transform x -> scale * rotation @ x + translation (scale 1: a rigid transform)."""

    rotation: np.ndarray
    translation: np.ndarray
    scale: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "rotation", np.asarray(self.rotation, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "translation", np.asarray(self.translation, dtype=np.float64).reshape(3))
        object.__setattr__(self, "scale", float(self.scale))

    @classmethod
    def identity(cls) -> Sim3:
        return cls(np.eye(3), np.zeros(3), 1.0)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform (N,3) points (or one point (3,))."""
        return self.scale * np.asarray(points, dtype=np.float64) @ self.rotation.T + self.translation

    def compose(self, other: Sim3) -> Sim3:
        """self ∘ other: first `other`, then `self` (target_from_mid ∘ mid_from_source)."""
        return Sim3(
            self.rotation @ other.rotation,
            self.scale * self.rotation @ other.translation + self.translation,
            self.scale * other.scale,
        )

    def inverse(self) -> Sim3:
        r_inv = self.rotation.T
        return Sim3(r_inv, -(r_inv @ self.translation) / self.scale, 1.0 / self.scale)

    def matrix(self) -> np.ndarray:
        """The 3x4 matrix [sR | t] (pycolmap.Sim3d accepts it)."""
        return np.hstack([self.scale * self.rotation, self.translation[:, None]])

    def to_dict(self) -> dict:
        return {"rotation": self.rotation.tolist(), "translation": self.translation.tolist(), "scale": self.scale}

    @classmethod
    def from_dict(cls, data: dict) -> Sim3:
        """The inverse of `to_dict` (a missing scale is 1: a rigid transform)."""
        return cls(data["rotation"], data["translation"], data.get("scale", 1.0))


def transform_error(estimate: Sim3, truth: Sim3, points: np.ndarray | None = None) -> tuple[float, float]:
    """(translation error m, rotation error deg) of `estimate` against `truth`.

    With `points` (source frame), the translation error is the RMS displacement of those points between the two
    transforms, which is what matters for a map (a small rotation error far from the origin is not a metre
    of error at the data); without them it is the distance between the translations.
    """
    rot = rotation_angle_deg(estimate.rotation, truth.rotation)
    if points is None or len(points) == 0:
        return float(np.linalg.norm(estimate.translation - truth.translation)), rot
    diff = estimate.apply(points) - truth.apply(points)
    return float(np.sqrt(np.mean(np.sum(diff**2, axis=1)))), rot


def umeyama(source: np.ndarray, target: np.ndarray, with_scale: bool = False) -> Sim3:
    """Least-squares transform with target ≈ s R source + t (Umeyama 1991; Arun et al. when rigid).

    Needs at least 3 non-collinear correspondences; raises ValueError otherwise.
    """
    src = np.asarray(source, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(target, dtype=np.float64).reshape(-1, 3)
    if len(src) != len(dst) or len(src) < 3:
        raise ValueError(f"need >= 3 correspondences of equal count, got {len(src)} and {len(dst)}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    if d[1] < 1e-12 * max(d[0], 1e-300):
        raise ValueError("correspondences are collinear; the rotation is not determined")
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:  # reflection: flip the weakest axis
        sign[2, 2] = -1.0
    rot = u @ sign @ vt
    scale = 1.0
    if with_scale:
        var_s = np.mean(np.sum(xs**2, axis=1))
        scale = float(np.trace(np.diag(d) @ sign) / var_s)
    return Sim3(rot, mu_d - scale * rot @ mu_s, scale)


@dataclass(frozen=True)
class Edge:
    """An accepted session pair: `a_from_b` maps session b's frame into session a's; weight ranks reliability."""

    a: int
    b: int
    a_from_b: Sim3
    weight: float


def connected_groups(num_nodes: int, edges: Iterable[Edge]) -> list[list[int]]:
    """Connected components of the session graph, each sorted, ordered by their smallest node."""
    parent = list(range(num_nodes))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for e in edges:
        ra, rb = find(e.a), find(e.b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    groups: dict[int, list[int]] = {}
    for i in range(num_nodes):
        groups.setdefault(find(i), []).append(i)
    return sorted(groups.values(), key=lambda g: g[0])


def spanning_transforms(group: Sequence[int], edges: Sequence[Edge]) -> tuple[int, dict[int, Sim3], list[Edge]]:
    """Bring every session of a connected group into one reference frame along a maximum spanning tree.

    The reference is the session with the largest total edge weight (ties: the smallest index), so the frame
    that most sessions agree with directly anchors the group. The tree keeps the heaviest edges (most
    associations), because a composed transform is only as good as its weakest link.
    Returns (reference, {session: reference_from_session}, tree edges).
    """
    members = set(group)
    inner = [e for e in edges if e.a in members and e.b in members]
    strength = {i: 0.0 for i in group}
    for e in inner:
        strength[e.a] += e.weight
        strength[e.b] += e.weight
    reference = min(group, key=lambda i: (-strength[i], i))
    adjacency: dict[int, list[tuple[int, Edge]]] = {i: [] for i in group}
    for k, e in enumerate(inner):
        adjacency[e.a].append((k, e))
        adjacency[e.b].append((k, e))
    ref_from = {reference: Sim3.identity()}
    tree: list[Edge] = []
    heap: list[tuple[float, int, int, int]] = []  # (-weight, edge order, from node, edge index) for determinism

    def push(node: int) -> None:
        for k, e in adjacency[node]:
            heapq.heappush(heap, (-e.weight, k, node, k))

    push(reference)
    while heap:
        _, _, node, k = heapq.heappop(heap)
        e = inner[k]
        other = e.b if node == e.a else e.a
        if other in ref_from:
            continue
        # node is in the tree: ref_from[other] = ref_from[node] ∘ node_from_other
        node_from_other = e.a_from_b if node == e.a else e.a_from_b.inverse()
        ref_from[other] = ref_from[node].compose(node_from_other)
        tree.append(e)
        push(other)
    if len(ref_from) != len(members):
        raise ValueError("group is not connected by the given edges")
    return reference, ref_from, tree


def fusion_groups(pairs: Iterable[tuple[int, int, np.ndarray]]) -> list[list[tuple[int, int]]]:
    """Group landmarks that associations say are the same object.

    `pairs`: (session a, session b, (K,2) int array of landmark index pairs (index in a, index in b)).
    Returns groups of (session, landmark index) with more than one member, each sorted, in sorted order.
    A group never holds two landmarks of one session when the pairs come from a spanning tree with one-to-one
    associations; for other inputs such groups are split off (the later landmark of that session is dropped
    from the group) so that a fused point never merges two observations of the same object within a session.
    """
    parent: dict[tuple[int, int], tuple[int, int]] = {}

    def find(x: tuple[int, int]) -> tuple[int, int]:
        parent.setdefault(x, x)
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for a, b, assoc in pairs:
        for ia, ib in np.asarray(assoc, dtype=np.int64).reshape(-1, 2):
            ra, rb = find((a, int(ia))), find((b, int(ib)))
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    groups: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for x in parent:
        groups.setdefault(find(x), []).append(x)
    out = []
    for members in groups.values():
        seen: set[int] = set()
        kept = []
        for s, i in sorted(members):
            if s not in seen:
                seen.add(s)
                kept.append((s, i))
        if len(kept) > 1:
            out.append(kept)
    return sorted(out)


def nearest_pairs(centers: np.ndarray, k: int) -> list[tuple[int, int]]:
    """Pairs (i < j) where j is among the k nearest sessions of i or i among those of j (by centre distance)."""
    c = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    n = len(c)
    if n < 2 or k <= 0:
        return []
    dist = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=2)
    np.fill_diagonal(dist, np.inf)
    order = np.argsort(dist, axis=1, kind="stable")[:, : min(k, n - 1)]
    pairs = {(min(i, int(j)), max(i, int(j))) for i in range(n) for j in order[i]}
    return sorted(pairs)


def consistent_edges(
    num_nodes: int, edges: Sequence[Edge], probes: Sequence[np.ndarray], tolerance_m: float
) -> tuple[list[Edge], list[Edge]]:
    """Keep the edges of the session graph that agree with each other; drop the ones that contradict.

    One wrong accepted pair is enough to put a session in the wrong place, and the spanning tree alone cannot
    tell: it trusts the heaviest edge. So components are joined greedily (heaviest edge between two components
    first), and when several edges connect the same two components, each proposes where the second component
    lies in the first one's frame; two proposals agree when they place every probe point of the second component
    (e.g. its sessions' mean camera positions) within `tolerance_m` of each other. A lone edge is taken as it is
    (nothing contradicts it). Otherwise the proposal agreed by the most edges (then the most weight) wins if at
    least two edges agree on it and no disagreeing proposal is agreed by as many; its agreeing edges are kept,
    the rest rejected. Wrong pairs rarely agree with each other, so corroboration, not |S|, decides. Without a
    winner the components are not joined and all those edges are rejected: two sessions left apart are better
    than a merged model that is wrong.
    `probes[i]`: (P,3) points in session i's frame. Returns (kept, rejected).
    """
    comp = list(range(num_nodes))
    members = {i: [i] for i in range(num_nodes)}
    root_from = [Sim3.identity() for _ in range(num_nodes)]  # component root from node
    kept: list[Edge] = []
    rejected: list[Edge] = []
    remaining = sorted(edges, key=lambda e: (-e.weight, e.a, e.b))
    while remaining:
        first = remaining[0]
        c1, c2 = comp[first.a], comp[first.b]
        if c1 == c2:  # cannot happen (edges inside a component are settled when it forms); stay safe
            remaining.pop(0)
            kept.append(first)
            continue
        between = [e for e in remaining if {comp[e.a], comp[e.b]} == {c1, c2}]
        taken = {id(e) for e in between}  # identity: Edge equality would compare numpy arrays
        remaining = [e for e in remaining if id(e) not in taken]
        proposals = []
        for e in between:
            if comp[e.a] == c1:  # r1_from_r2 = r1_from_a ∘ a_from_b ∘ b_from_r2
                prop = root_from[e.a].compose(e.a_from_b).compose(root_from[e.b].inverse())
            else:
                prop = root_from[e.b].compose(e.a_from_b.inverse()).compose(root_from[e.a].inverse())
            proposals.append(prop)
        pts = np.vstack([root_from[n].apply(np.asarray(probes[n], dtype=np.float64).reshape(-1, 3))
                         for n in members[c2]])
        placed = [p.apply(pts) for p in proposals]
        agree = np.array([[np.max(np.linalg.norm(pi - pj, axis=1)) <= tolerance_m for pj in placed] for pi in placed])
        weights = np.array([e.weight for e in between])
        count = agree.sum(axis=1)
        best = max(range(len(between)), key=lambda k: (count[k], agree[k] @ weights, -k))
        rivals = [k for k in range(len(between)) if not agree[best, k] and count[k] >= count[best]]
        if (count[best] == 1 and len(between) > 1) or rivals:  # contradicted and not corroborated: keep apart
            rejected.extend(between)
            continue
        kept.extend(e for e, ok in zip(between, agree[best]) if ok)
        rejected.extend(e for e, ok in zip(between, agree[best]) if not ok)
        r1_from_r2 = proposals[best]
        for n in members[c2]:
            root_from[n] = r1_from_r2.compose(root_from[n])
            comp[n] = c1
        members[c1].extend(members.pop(c2))
    return kept, rejected


# --- refining a pairwise alignment on the full maps --------------------------------------------------------------


def fit_yaw_translation(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None,
                        with_scale: bool = False) -> Sim3:
    """Weighted least-squares 4-DOF transform target ≈ Rz(yaw) source + t (gravity-aligned frames); with
    `with_scale` 5-DOF, target ≈ s Rz(yaw) source + t with the scale fitted on the horizontal coordinates.

    Both maps' z axes point up (roll and pitch are observable from gravity, the premise of the method's gravity
    check), so only the yaw and the translation are unknown. Fitting 4 instead of 6 degrees of freedom keeps
    the metre-level vertical noise of landmarks out of the rotation. Needs horizontal spread in the points;
    raises ValueError otherwise.
    """
    src = np.asarray(source, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(target, dtype=np.float64).reshape(-1, 3)
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if len(src) != len(dst) or len(src) != len(w) or len(src) < 2 or w.sum() <= 0:
        raise ValueError(f"need >= 2 weighted correspondences of equal count, got {len(src)} and {len(dst)}")
    w = w / w.sum()
    mu_s, mu_d = w @ src, w @ dst
    xs, xd = src - mu_s, dst - mu_d
    num = w @ (xs[:, 0] * xd[:, 1] - xs[:, 1] * xd[:, 0])
    den = w @ (xs[:, 0] * xd[:, 0] + xs[:, 1] * xd[:, 1])
    spread = float(w @ np.sum(xs[:, :2] ** 2, axis=1))
    if np.hypot(num, den) < 1e-12 * max(spread, 1e-300):
        raise ValueError("correspondences have no horizontal spread; the yaw is not determined")
    yaw = np.arctan2(num, den)
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    scale = float(np.hypot(num, den) / spread) if with_scale else 1.0
    return Sim3(rot, mu_d - scale * rot @ mu_s, scale)


def mutual_nearest(
    points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
    gate_m: float, max_size_difference: float, z_weight: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Mutual nearest neighbours between two landmark maps already in one frame.

    Candidates are pairs within `gate_m` under the distance sqrt(dx² + dy² + (z_weight dz)²) (landmark heights
    are noisier than their ground positions) whose relative size difference is at most `max_size_difference`
    (sizes NaN or None: no size gate). A pair is kept when each is the other's nearest candidate.
    Returns ((K,2) landmark index pairs (A, B) sorted by A, (K,) distances).
    """
    from scipy.spatial import cKDTree

    scale = np.array([1.0, 1.0, z_weight])
    pa = np.asarray(points_a, dtype=np.float64).reshape(-1, 3) * scale
    pb = np.asarray(points_b, dtype=np.float64).reshape(-1, 3) * scale
    empty = (np.zeros((0, 2), np.int64), np.zeros(0))
    if not len(pa) or not len(pb):
        return empty
    pairs = cKDTree(pa).sparse_distance_matrix(cKDTree(pb), gate_m, output_type="ndarray")
    i, j, d = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64), pairs["v"]
    if sizes_a is not None and sizes_b is not None:
        ok = size_ratio(np.asarray(sizes_a, np.float64)[i], np.asarray(sizes_b, np.float64)[j]) <= max_size_difference
        i, j, d = i[ok], j[ok], d[ok]
    if not len(i):
        return empty
    # nearest candidate of every A landmark and of every B landmark (ties: lower index), then keep mutual ones
    best_a = np.full(len(pa), -1, np.int64)
    order = np.lexsort((j, d, i))
    first = np.r_[True, i[order][1:] != i[order][:-1]]
    best_a[i[order][first]] = j[order][first]
    best_b = np.full(len(pb), -1, np.int64)
    order = np.lexsort((i, d, j))
    first = np.r_[True, j[order][1:] != j[order][:-1]]
    best_b[j[order][first]] = i[order][first]
    keep = (best_a[i] == j) & (best_b[j] == i)
    order = np.argsort(i[keep], kind="stable")
    return np.column_stack([i[keep], j[keep]])[order], d[keep][order]


@dataclass(frozen=True)
class Alignment:
    """A pairwise alignment refined on the full maps (`refine_alignment`)."""

    transform: Sim3  # a_from_b
    associations: np.ndarray  # (K,2) mutual nearest neighbours that support it (index in A, index in B)
    rms_m: float  # RMS residual of the supporting associations (weighted distance of `mutual_nearest`)
    iterations: int


def refine_alignment(
    points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
    initial: Sim3, gate_m: float, max_size_difference: float, dof: int = 4, with_scale: bool = False,
    max_iterations: int = 20, z_weight: float = 0.5,
) -> Alignment:
    """Refine a_from_b on every landmark the two maps share, not only on one window's associations.

    Iterates (ICP with a size gate): move B by the current transform, pair landmarks by `mutual_nearest`
    within `gate_m`, refit with Huber weights (residuals beyond gate_m / 2 count less, so a wrong pair near the
    gate pulls little), until the set of pairs stops changing. `dof` 4 fits yaw + translation
    (`fit_yaw_translation`, for gravity-aligned maps); 6 a rigid (or with `with_scale` a similarity) transform.
    Keeps `initial` (and its supporting pairs) when fewer than 3 pairs are found.
    """
    if dof not in (4, 6):
        raise ValueError(f"dof must be 4 or 6, got {dof}")
    pa = np.asarray(points_a, dtype=np.float64).reshape(-1, 3)
    pb = np.asarray(points_b, dtype=np.float64).reshape(-1, 3)
    transform = initial
    assoc, dist = mutual_nearest(pa, sizes_a, transform.apply(pb), sizes_b, gate_m, max_size_difference, z_weight)
    iterations = 0
    while iterations < max_iterations and len(assoc) >= 3:
        iterations += 1
        w = _huber_weights(dist, gate_m)
        try:
            if dof == 4:
                new = fit_yaw_translation(pb[assoc[:, 1]], pa[assoc[:, 0]], w)
            else:
                new = _weighted_umeyama(pb[assoc[:, 1]], pa[assoc[:, 0]], w, with_scale)
        except ValueError:
            break
        new_assoc, new_dist = mutual_nearest(pa, sizes_a, new.apply(pb), sizes_b, gate_m, max_size_difference,
                                             z_weight)
        if len(new_assoc) < 3:
            break
        same = np.array_equal(new_assoc, assoc)
        transform, assoc, dist = new, new_assoc, new_dist
        if same:
            break
    rms = float(np.sqrt(np.mean(dist**2))) if len(dist) else float("nan")
    return Alignment(transform, assoc, rms, iterations)


def _weighted_umeyama(source: np.ndarray, target: np.ndarray, weights: np.ndarray, with_scale: bool) -> Sim3:
    """`umeyama` with per-correspondence weights (rows repeated in proportion would give the same result)."""
    w = np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    mu_s, mu_d = w @ source, w @ target
    xs, xd = source - mu_s, target - mu_d
    cov = (xd * w[:, None]).T @ xs
    u, d, vt = np.linalg.svd(cov)
    if d[1] < 1e-12 * max(d[0], 1e-300):
        raise ValueError("correspondences are collinear; the rotation is not determined")
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1.0
    rot = u @ sign @ vt
    scale = float(np.trace(np.diag(d) @ sign) / (w @ np.sum(xs**2, axis=1))) if with_scale else 1.0
    return Sim3(rot, mu_d - scale * rot @ mu_s, scale)


@dataclass(frozen=True)
class Verification:
    """The outcome of `verify_alignments`: the best-supported refined alignment and how clearly it won."""

    best: Alignment | None  # None when no candidate could be refined
    runner_up_support: int  # support of the best alignment that disagrees with `best` (0 if none)
    num_refined: int  # candidates refined (the others agreed with an alignment already refined)
    accepted: bool


def _agree(t1: Sim3, t2: Sim3, points: np.ndarray, tolerance_m: float) -> bool:
    return bool(len(points) and np.max(np.linalg.norm(t1.apply(points) - t2.apply(points), axis=1)) <= tolerance_m)


def verify_alignments(
    points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray, sizes_b: np.ndarray | None,
    candidates: Sequence[tuple[Sim3, np.ndarray]], gate_m: float, max_size_difference: float,
    min_support: int, min_ratio: float = 1.2, dof: int = 4, z_weight: float = 0.5, final_dof: int | None = 6,
) -> Verification:
    """Choose among a pair's window hypotheses by their support on the FULL maps, and refine the winner.

    One window pair sees 50 x 50 landmarks; across seasons a true hypothesis there has |S| ~ 5-9, and so do
    chance-consistent wrong ones, so |S| cannot tell them apart. Over the full maps it can: a correct transform
    brings many more landmarks of B onto landmarks of A than a wrong one. Every candidate (transform, (K,)
    indices of its B landmarks), largest first, is refined by `refine_alignment` unless it already agrees with
    a candidate tried before or its refined result (its B landmarks land within gate_m of where that one puts
    them). The
    alignment with the most mutual-nearest-neighbour support wins; it is accepted when that support exceeds
    `min_support` and is at least `min_ratio` times the support of the best rival (an alignment that moves some
    of the winner's supporting B landmarks more than 2 gate_m away from where the winner puts them: the search's
    other candidates, and B deliberately displaced and turned (`_displaced_starts`), refined like the winner).
    `final_dof` 6: the winner's transform is finally refitted rigidly (6-DOF, Huber-weighted) on its supporting
    pairs, and its support is the mutual nearest neighbours under that transform. The 4-DOF search finds the
    pairs robustly; with tens to hundreds of pairs over the whole overlap the small tilt between two EKF frames
    (~1 deg on the synthetic winter flights) is then observable, which one window's 8-20 inliers could not
    resolve, and the landmarks that the tilt kept out of the 4-DOF pairs join. None: keep the `dof` fit.
    """
    pb_all = np.asarray(points_b, dtype=np.float64).reshape(-1, 3)
    refined: list[Alignment] = []
    tried: list[Sim3] = []  # the starting transforms and where they converged: a candidate near either is done
    for transform, idx_b in candidates:
        probe = pb_all[np.asarray(idx_b, dtype=np.int64).reshape(-1)]
        if any(_agree(transform, t, probe, gate_m) for t in tried):
            continue
        tried.append(transform)
        refined.append(refine_alignment(points_a, sizes_a, points_b, sizes_b, transform, gate_m,
                                        max_size_difference, dof=dof, z_weight=z_weight))
        tried.append(refined[-1].transform)
    if not refined:
        return Verification(None, 0, 0, False)
    order = sorted(range(len(refined)), key=lambda k: (-len(refined[k].associations), refined[k].rms_m, k))
    best = refined[order[0]]
    probe = pb_all[best.associations[:, 1]]
    # A rival puts B somewhere else: more than 2 gates away. Refinements that converged within that distance
    # are the same alignment caught on a slightly different set of chance pairs (seen across seasons: 2-3 m
    # apart with |support| within 1), i.e. its uncertainty, not a contradiction.
    rivals = [len(refined[k].associations) for k in order[1:]
              if not _agree(best.transform, refined[k].transform, probe, 2.0 * gate_m)]
    # The rivals the search offered are not enough: with one candidate there is none, and a chance alignment of
    # two unrelated maps then won by default (3 of 8 pairs of different synthetic worlds were "verified" with
    # 8-15 pairs). B deliberately put elsewhere and refined like the winner is the chance level at this map
    # density and these gates: the winner must beat it by min_ratio too.
    pa_all = np.asarray(points_a, dtype=np.float64).reshape(-1, 3)
    for start in _displaced_starts(best.transform, pb_all, gate_m):
        control = refine_alignment(pa_all, sizes_a, pb_all, sizes_b, start, gate_m, max_size_difference, dof=dof,
                                   z_weight=z_weight)
        if not _agree(best.transform, control.transform, probe, 2.0 * gate_m):
            rivals.append(len(control.associations))
    runner_up = max(rivals, default=0)
    support = len(best.associations)
    if final_dof == 6 and dof != 6 and support >= 3:
        first = _final_rigid_fit(pa_all, pb_all, best, gate_m, z_weight)
        # then the pairs under that transform: landmarks the 4-DOF fit could not reach because the frames are
        # tilted (1-2 deg between EKF frames is metres of height at the far end of a map) join its support
        assoc, dist = mutual_nearest(pa_all, sizes_a, first.transform.apply(pb_all), sizes_b, gate_m,
                                     max_size_difference, z_weight)
        best = first
        if len(assoc) >= len(first.associations):
            best = Alignment(first.transform, assoc, float(np.sqrt(np.mean(dist**2))), first.iterations)
    accepted = support > min_support and support >= min_ratio * runner_up
    return Verification(best, runner_up, len(refined), accepted)


CONTROL_SHIFT_GATES = 3.0  # the displaced controls: B moved this many gates (beyond any landmark scatter)
CONTROL_YAWS_DEG = (-10.0, 10.0, 180.0)  # and B turned about its centre (a flight's lines, its reverse)


def _displaced_starts(transform: Sim3, points_b: np.ndarray, gate_m: float) -> list[Sim3]:
    """The winner's transform with B moved CONTROL_SHIFT_GATES gates in 6 horizontal directions and turned by
    CONTROL_YAWS_DEG about B's centre (in A's frame): starts of alignments that put B elsewhere."""
    starts = []
    for k in range(6):
        ang = k * np.pi / 3.0
        shift = CONTROL_SHIFT_GATES * gate_m * np.array([np.cos(ang), np.sin(ang), 0.0])
        starts.append(Sim3(transform.rotation, transform.translation + shift, transform.scale))
    centre = transform.apply(points_b).mean(axis=0) if len(points_b) else np.zeros(3)
    for yaw in CONTROL_YAWS_DEG:
        c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
        turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        starts.append(Sim3(turn @ transform.rotation, turn @ (transform.translation - centre) + centre,
                           transform.scale))
    return starts


def verification_candidates(hypotheses: Sequence[Any], max_gravity_angle_deg: float,
                            max_candidates: int = 400) -> list[tuple[Sim3, np.ndarray]]:
    """The candidates `verify_alignments` takes from a search's window hypotheses (objects with `size`,
    `transform` (rotation, translation, scale; None when degenerate), `tilt_deg`, `associations`): those that
    pass the gravity check, largest |S| first (stable), at most `max_candidates` (bounds the work on dense
    same-season maps), each as (a_from_b, indices of its B landmarks)."""
    usable = [h for h in hypotheses if h.transform is not None and h.tilt_deg <= max_gravity_angle_deg]
    usable.sort(key=lambda h: -h.size)
    return [(Sim3(h.transform.rotation, h.transform.translation, h.transform.scale),
             np.asarray(h.associations, dtype=np.int64).reshape(-1, 2)[:, 1]) for h in usable[:max_candidates]]


def _final_rigid_fit(pa: np.ndarray, pb: np.ndarray, aligned: Alignment, gate_m: float, z_weight: float) -> Alignment:
    """One Huber-weighted 6-DOF fit on an alignment's supporting pairs (kept as they are)."""
    assoc = aligned.associations
    src, dst = pb[assoc[:, 1]], pa[assoc[:, 0]]
    scale = np.array([1.0, 1.0, z_weight])  # the distance `mutual_nearest` pairs by
    w = _huber_weights(np.linalg.norm((aligned.transform.apply(src) - dst) * scale, axis=1), gate_m)
    try:
        rigid = _weighted_umeyama(src, dst, w, with_scale=False)
    except ValueError:
        return aligned
    res = np.linalg.norm((rigid.apply(src) - dst) * scale, axis=1)
    return Alignment(rigid, assoc, float(np.sqrt(np.mean(res**2))), aligned.iterations)


def _huber_weights(dist: np.ndarray, gate_m: float) -> np.ndarray:
    """IRLS weights of a Huber loss at half the gate: 1 inside, falling as 1/distance beyond (a wrong pair near
    the gate pulls little)."""
    huber = gate_m / 2.0
    return np.where(dist <= huber, 1.0, huber / np.maximum(dist, 1e-12))


def verify_search(points_a: np.ndarray, sizes_a: np.ndarray | None, points_b: np.ndarray,
                  sizes_b: np.ndarray | None, hypotheses: Sequence, association: object,
                  verification: object) -> Verification:
    """The verified answer of a windowed search: its hypotheses checked and refined on the full maps.

    `hypotheses`: the search's `WindowHypothesis` list; every one with a transform that passes the gravity check
    is a candidate, largest |S| first (at most `verification.max_candidates`), and `verify_alignments` chooses
    among them with the search's theta_eps, the verification's size gate and support > theta_S. `association`,
    `verification`: `AssociationParams`, `VerificationParams`.
    """
    sims = verification_candidates(hypotheses, association.max_gravity_angle_deg, verification.max_candidates)
    return verify_alignments(np.asarray(points_a, np.float64), sizes_a, np.asarray(points_b, np.float64), sizes_b,
                             sims, association.distance_tolerance_m, verification.max_size_difference,
                             association.min_associations, min_ratio=verification.min_ratio, dof=verification.dof,
                             z_weight=verification.z_weight, final_dof=verification.final_dof or None)
