"""Multi-session geometry and graph algorithms (pure numpy): similarity transforms, Umeyama alignment,
the session graph (connected groups, spanning-tree transforms into one reference frame), landmark fusion groups
and nearest-session pairs. Refining a pair's alignment on the full maps is `plugin.refinement`, verifying a
match `plugin.verification`.

Transform convention: a `Sim3` maps points of a *source* frame into a *target* frame, x_t = s R x_s + t.
For a session pair (A, B) the stored transform is `a_from_b` (B's landmarks into A's frame), as in match.json.
"""

from __future__ import annotations

import heapq
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

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

    def displacement(self, points: np.ndarray) -> np.ndarray:
        """|T(p) - p| of each (N,3) point: how far the transform moves it. The translation is only the move of
        the origin: a 2.7 deg roll about landmarks 300 m from the origin translates it 16 m and moves them 1.9 m;
        between frames of different origins (a UTM map against a local one) every point moves by their offset."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return np.linalg.norm(self.apply(pts) - pts, axis=1)

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
    """An accepted session pair: `a_from_b` maps session b's frame into session a's; weight ranks reliability.
    `imprecise`: the pair's own predicted error at B's landmarks exceeds its gate (match.json's
    `answer_uncertainty.imprecise`), so alone it may not join two groups (`consistent_edges`)."""

    a: int
    b: int
    a_from_b: Sim3
    weight: float
    imprecise: bool = False


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


# a georeference counts as more precise than another only when its measured noise is less than 1 / this of the
# other's: one flight's measured noise is itself uncertain by tens of percent, and among comparable ones the
# session most others agree with directly anchors the group
PRECISE_GEOREFERENCE_FACTOR = 2.0


def spanning_transforms(group: Sequence[int], edges: Sequence[Edge], preferred: Collection[int] = (),
                        noise_m: Mapping[int, float] | None = None,
                        keep: Collection[int] = ()) -> tuple[int, dict[int, Sim3], list[Edge]]:
    """Bring every session of a connected group into one reference frame along a maximum spanning tree.

    The reference is the session with the largest total edge weight (ties: the smallest index), so the frame
    that most sessions agree with directly anchors the group; when some members are `preferred` (georeferenced
    sessions: their frame is a map projection, any other is arbitrary), it is the strongest of those, so the
    merged model keeps the group's georeference (a local reference dropped it: a DJI-tagged flight merged with
    five local ones gave a model no GIS could place). `noise_m`: the measured noise of a preferred session's
    georeference (its GPS positions'; absent: not known): one more than `PRECISE_GEOREFERENCE_FACTOR` times
    noisier than the most precise, or of unknown noise, is not the reference (nu34: an RTK session, 0.05 m,
    merged in the frame of a 1.4 m GPS session named first, its landmarks 0.56 m off instead of 0.26). The tree
    keeps the heaviest edges (most associations), because a composed transform is only as good as its weakest
    link (a maximum spanning tree from any reference). `keep`: sessions that were the reference of an earlier
    run of the same output (a batch resumed with flights added): the reference stays one of them while it is as
    eligible as above (the strongest of them), because strength depends on which flights there are, and a
    reference that moves with every added flight moves the merged model into another frame and another folder
    (nu40: f6 added to five flights moved it from f1 to f5).
    Returns (reference, {session: reference_from_session}, tree edges).
    """
    members = set(group)
    inner = [e for e in edges if e.a in members and e.b in members]
    strength = {i: 0.0 for i in group}
    for e in inner:
        strength[e.a] += e.weight
        strength[e.b] += e.weight
    candidates = [i for i in group if i in preferred] or list(group)
    known = [noise_m[i] for i in candidates if noise_m and i in noise_m]
    if known and noise_m:  # a georeference of unknown precision is not known to be as good as the best measured
        best = min(known)
        candidates = [i for i in candidates if i in noise_m and noise_m[i] <= PRECISE_GEOREFERENCE_FACTOR * best]
    candidates = [i for i in candidates if i in keep] or candidates
    reference = min(candidates, key=lambda i: (-strength[i], i))
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


def one_to_one(associations: np.ndarray, distances: np.ndarray, admissible: np.ndarray | None = None) -> np.ndarray:
    """Indices of a one-to-one subset of (K,2) `associations` (landmark in a, landmark in b), nearest first.

    Greedy by ascending distance (ties: the smaller a index, then b index): an association is taken when neither
    of its landmarks is taken already, so each one taken is the mutual nearest of what remains. An unverified
    match (a window consensus) may pair one landmark of A with three of B; grouped as they come, a chain of such
    pairs fused two landmarks 5.7 m apart under a 2.95 m gate (rev33). `admissible` (bool per association): only
    those may be taken (e.g. within the gate). Returns the taken indices in the order taken (nearest first)."""
    assoc = np.asarray(associations, dtype=np.int64).reshape(-1, 2)
    dist = np.asarray(distances, dtype=np.float64).reshape(-1)
    ok = np.ones(len(assoc), bool) if admissible is None else np.asarray(admissible, bool).reshape(-1)
    taken_a: set[int] = set()
    taken_b: set[int] = set()
    out = []
    for k in np.lexsort((assoc[:, 1], assoc[:, 0], dist)):
        ia, ib = int(assoc[k, 0]), int(assoc[k, 1])
        if ok[k] and ia not in taken_a and ib not in taken_b:
            taken_a.add(ia)
            taken_b.add(ib)
            out.append(int(k))
    return np.asarray(out, dtype=np.int64)


def fusion_groups(pairs: Iterable[tuple[int, int, np.ndarray]]) -> list[list[tuple[int, int]]]:
    """Group landmarks that associations say are the same object.

    `pairs`: (session a, session b, (K,2) int array of landmark index pairs (index in a, index in b)).
    Returns groups of (session, landmark index) with more than one member, each sorted, in sorted order.
    Associations are taken in the order given (each pair's, pair after pair): one joins its two landmarks' groups
    only when they hold no session in common, so a group never holds two landmarks of one session (a fused point
    never merges two objects of one session) and every association is either inside one group or refused whole
    (`associations_not_fused` counts those; before rev33's mend a group kept the first landmark of each session,
    associated or not).
    """
    parent: dict[tuple[int, int], tuple[int, int]] = {}
    sessions_of: dict[tuple[int, int], set[int]] = {}

    def find(x: tuple[int, int]) -> tuple[int, int]:
        if x not in parent:
            parent[x] = x
            sessions_of[x] = {x[0]}
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for a, b, assoc in pairs:
        for ia, ib in np.asarray(assoc, dtype=np.int64).reshape(-1, 2):
            ra, rb = find((a, int(ia))), find((b, int(ib)))
            if ra != rb and not sessions_of[ra] & sessions_of[rb]:
                root, other = min(ra, rb), max(ra, rb)
                parent[other] = root
                sessions_of[root] |= sessions_of.pop(other)
    groups: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for x in parent:
        groups.setdefault(find(x), []).append(x)
    return sorted(sorted(members) for members in groups.values() if len(members) > 1)


def associations_not_fused(pairs: Iterable[tuple[int, int, np.ndarray]], groups: Sequence[Sequence[tuple[int, int]]]
                           ) -> int:
    """How many of `pairs`' associations do not have both landmarks in one of `groups` (`fusion_groups`)."""
    group_of = {member: g for g, members in enumerate(groups) for member in members}
    missed = 0
    for a, b, assoc in pairs:
        for ia, ib in np.asarray(assoc, dtype=np.int64).reshape(-1, 2):
            ga, gb = group_of.get((a, int(ia))), group_of.get((b, int(ib)))
            missed += ga is None or ga != gb
    return missed


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
) -> tuple[list[Edge], list[Edge], list[Edge]]:
    """Keep the edges of the session graph that agree with each other; drop the ones that contradict.

    One wrong accepted pair is enough to put a session in the wrong place, and the spanning tree alone cannot
    tell: it trusts the heaviest edge. So components are joined greedily (heaviest edge between two components
    first), and when several edges connect the same two components, each proposes where the second component
    lies in the first one's frame; two proposals agree when they place every probe point of the second component
    (e.g. its sessions' mean camera positions) within `tolerance_m` of each other. A lone edge is taken as it is
    (nothing contradicts it), unless it is `imprecise`: an answer that cannot place B within its own gate is no
    evidence enough to join two groups on its own (nu44: two disjoint tiles of one map verified, p 0.001, B up
    to 58 m off by the answer's own uncertainty); it joins only when another edge agrees with it. Imprecise edges
    are therefore taken after every precise one, so a path of precise edges between their sessions can
    corroborate (or contradict) them, and one set aside is judged again with any edge that later connects the
    same two groups. Otherwise the proposal agreed by the most edges (then the most weight) wins if at least two
    edges agree on it and no disagreeing proposal is agreed by as many; its agreeing edges are kept, the rest
    rejected. Where precise edges connect the two groups, they alone decide: an imprecise answer may miss by more
    than the tolerance by its own account, so it neither blocks nor outvotes them (kept when it agrees with their
    winner, rejected otherwise; rev27: one imprecise edge 8 m off kept a precise join apart). Wrong pairs rarely
    agree with each other, so corroboration, not |S|, decides. Without a winner the components are not joined and
    all those edges are rejected: two sessions left apart are better than a merged model that is wrong. Graphs of
    precise edges only are treated exactly as before. (Three imprecise edges that close a triangle and nothing
    else are all left out: none of them ever connects two groups another edge connects.)
    `probes[i]`: (P,3) points in session i's frame. Returns (kept, contradicted, uncorroborated): the edges
    joined, those rejected because others disagree, and lone imprecise edges left out for want of support.
    """
    comp = list(range(num_nodes))
    members = {i: [i] for i in range(num_nodes)}
    root_from = [Sim3.identity() for _ in range(num_nodes)]  # component root from node
    kept: list[Edge] = []
    rejected: list[Edge] = []
    deferred: list[Edge] = []  # lone imprecise edges set aside, judged again if another edge joins their groups
    remaining = sorted(edges, key=lambda e: (e.imprecise, -e.weight, e.a, e.b))
    while remaining:
        first = remaining[0]
        c1, c2 = comp[first.a], comp[first.b]
        if c1 == c2:  # cannot happen (edges inside a component are settled when it forms); stay safe
            remaining.pop(0)
            kept.append(first)
            continue
        between = [e for e in remaining + deferred if {comp[e.a], comp[e.b]} == {c1, c2}]
        taken = {id(e) for e in between}  # identity: Edge equality would compare numpy arrays
        remaining = [e for e in remaining if id(e) not in taken]
        deferred = [e for e in deferred if id(e) not in taken]
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
        # the edges that decide: the precise ones where there are any (an imprecise one may miss by more than the
        # tolerance by its own account), else all
        precise = np.array([not e.imprecise for e in between])
        judges = precise if precise.any() else np.ones(len(between), bool)
        weights = np.array([e.weight for e in between]) * judges
        count = (agree & judges[None, :]).sum(axis=1)
        best = max(np.flatnonzero(judges), key=lambda k: (count[k], agree[k] @ weights, -k))
        rivals = [k for k in np.flatnonzero(judges) if not agree[best, k] and count[k] >= count[best]]
        if (count[best] == 1 and judges.sum() > 1) or rivals:  # contradicted and not corroborated: keep apart
            rejected.extend(between)
            continue
        if len(between) == 1 and between[0].imprecise:  # nothing contradicts it, nothing supports it either
            deferred.append(between[0])
            continue
        kept.extend(e for e, ok in zip(between, agree[best]) if ok)
        rejected.extend(e for e, ok in zip(between, agree[best]) if not ok)
        r1_from_r2 = proposals[best]
        for n in members[c2]:
            root_from[n] = r1_from_r2.compose(root_from[n])
            comp[n] = c1
        members[c1].extend(members.pop(c2))
    return kept, rejected, deferred
