"""The verification's chance model: the winner of a search is the best of very many alignments, so it must be
improbable as the best of that many chance alignments, not only beat one rival (maps of different worlds were
verified by the ratio test alone)."""

import json

import numpy as np
import pytest

from sosmatch.database.landmark_map import LandmarkMap, write_landmark_map
from sosmatch.database.match_io import read_match
from sosmatch.plugin.association.synthetic import survey_map_pair
from sosmatch.plugin.chance import CHANCE_MARGIN, chance_interval, chance_test, effective_trials
from sosmatch.plugin.multisession import Sim3
from sosmatch.plugin.refinement import refine_alignment
from sosmatch.plugin.verification import verify_alignments
from sosmatch.tools.cli import main


def _yaw(deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_the_best_of_many_chance_alignments_is_refused(monkeypatch):
    """Two unrelated maps (a sparse B over a denser A): the best of 500 random refined placements, as a search
    would offer it, beats the displaced controls by the ratio (accepted without the chance model and the layout's
    rivals on 2 of these 3 map pairs), but chance reaches it easily somewhere among the ~1e5 alignments: refused
    on all 3. (The layout's rivals, `plugin.layout_rivals`, are the best-landing of ~100 placements and refuse
    these by the ratio too; left out here to show what the chance model alone does.)"""
    import sosmatch.plugin.verification as verification

    ratio_only = []
    for seed in range(3):
        rng = np.random.default_rng(seed)
        a = np.column_stack([rng.uniform(0, 250, (300, 2)), rng.normal(0, 0.3, 300)])
        b = np.column_stack([rng.uniform(0, 250, (80, 2)), rng.normal(0, 0.3, 80)])
        starts = np.random.default_rng(1)
        best = None
        for _ in range(500):
            turn, target = _yaw(starts.uniform(0, 360)), np.r_[starts.uniform(0, 250, 2), 0.0]
            al = refine_alignment(a, None, b, None, Sim3(turn, target - turn @ b.mean(0)), 3.0, 0.4)
            if best is None or len(al.associations) > len(best.associations):
                best = al
        cand = [(best.transform, best.associations[:, 1])]
        assert len(best.associations) > 6  # chance alone passes theta_S
        with monkeypatch.context() as m:
            m.setattr(verification, "layout_starts", lambda *args: [])
            ratio_only.append(verify_alignments(a, None, b, None, cand, 3.0, 0.4, 6, chance_starts=0).accepted)
        v = verify_alignments(a, None, b, None, cand, 3.0, 0.4, 6)
        assert not v.accepted and not v.clear and v.chance.p_value > 0.5 and v.chance.trials > 1e4
    assert sum(ratio_only) >= 1


def test_chance_test_counts_the_trials_and_the_overdispersion():
    rng = np.random.default_rng(0)
    samples = rng.poisson(3.0, 64)
    one = chance_test(samples, 15, 1.0)
    many = chance_test(samples, 15, 1e5)
    assert 0 < one.p_value < many.p_value <= 1 and abs(one.p_value - one.tail) < 1e-12
    # the same mean, more spread (placements over more and less of A): a fatter tail, a larger p-value
    spread = chance_test(np.concatenate([samples[:32] * 0, samples[32:] * 2]), 15, 1e5)
    assert spread.variance > many.variance and spread.p_value > many.p_value
    # every random start reached the winner: no chance measured is not chance 0 (one pseudo-sample of 1)
    assert chance_test(np.zeros(0, int), 15, 1e5).mean == 1.0


def test_a_position_prior_shrinks_the_trials():
    rng = np.random.default_rng(0)
    a = np.column_stack([rng.uniform(0, 600, (500, 2)), np.zeros(500)])
    b = a[:250]
    free = effective_trials(a, b, 3.0)
    assert 1e5 < free < 1e7  # 600 m at a 3 m gate, every yaw
    assert effective_trials(a, b, 3.0, prior_m=30.0) < free / 100
    # a prior wider than the map counts the disc its chance samples cover, placements off A included (min(box,
    # disc) with samples over the whole disc undercounted the trials of a map smaller than the prior: rev32 F3)
    assert effective_trials(a, b, 3.0, prior_m=1e3) == pytest.approx(free * np.pi * 1e6 / 600**2, rel=0.01)


def _write(path, points, sizes):
    write_landmark_map(path, LandmarkMap(points, sizes, points.mean(0).round()))


def test_match_refuses_maps_of_different_worlds_and_records_the_chance(tmp_path, capsys):
    """Dense maps (3000 landmarks per km^2) and theta_S 3, so that chance hypotheses between maps of two
    different worlds reach the verification."""
    one = survey_map_pair(250, seed=31, density_per_km2=3000)
    other = survey_map_pair(120, seed=41, density_per_km2=3000)
    _write(tmp_path / "a.sosmap", one.points_a, one.sizes_a)
    _write(tmp_path / "b.sosmap", one.points_b, one.sizes_b)
    _write(tmp_path / "elsewhere.sosmap", other.points_b, other.sizes_b)
    loose = ["--set", "association.min_associations=3", "--set", "association.max_size_difference=0.4", "--no-plot"]
    assert main(["match", str(tmp_path / "a.sosmap"), str(tmp_path / "b.sosmap"), "--out", str(tmp_path / "same"),
                 *loose]) == 0
    assert "chance p" in capsys.readouterr().out
    doc = json.loads((tmp_path / "same" / "match.json").read_text())
    ver = doc["verification"]
    assert ver["accepted"] and ver["clear"]
    assert ver["chance"]["p_value"] <= ver["chance"]["false_alarm"] == doc["params"]["verification"]["false_alarm"]
    assert ver["chance"]["trials"] > 1e3 and ver["chance"]["samples"] > 0 and ver["support_dof"] > 50
    # window hypotheses lend the verified answer their associations; they say whether they agree with it
    agree = [h["agrees_with_answer"] for h in doc["hypotheses"] if h["accepted"]]
    assert agree and all(isinstance(x, bool) for x in agree) and any(agree)

    assert main(["match", str(tmp_path / "a.sosmap"), str(tmp_path / "elsewhere.sosmap"), "--out",
                 str(tmp_path / "different"), *loose]) == 0
    # the line names no match and nothing "accepted" (the window hypotheses over theta_S are chance here)
    line = capsys.readouterr().out
    assert "verification: no match" in line and "accepted" not in line and "over theta_S" in line
    assert "the best candidate holds" in line and "B placed elsewhere" in line
    doc = json.loads((tmp_path / "different" / "match.json").read_text())
    ver = doc["verification"]
    assert doc["num_accepted"] > 0 and ver["support"] > 3  # chance hypotheses were verified
    assert not ver["accepted"] and ver["chance"]["p_value"] > ver["chance"]["false_alarm"]
    assert not read_match(tmp_path / "different" / "match.json").accepted  # what every consumer reads
    assert all(h["agrees_with_answer"] is None for h in doc["hypotheses"])


def test_yaw_only_fits_of_one_tilted_alignment_are_no_rivals():
    """Two 1.9 km maps tilted 1 deg against each other (17 m of height 1 km away): 4-DOF refinements from
    different window hypotheses each hold a band of the map and disagree by more than 2 gates, but their pairs are
    those of the winner's rigid alignment, so they are the winner, not rivals. Refused before (support 77 against
    a "rival" of 76), which sends the default path to its second, much slower search (bench_match --only
    derived)."""
    from sosmatch.plugin.association import search
    from sosmatch.plugin.params import Params
    from sosmatch.plugin.verification import verify_search

    s = survey_map_pair(1000, seed=4, noise_m=1.0, size_noise=0.25, tilt_deg=1.0)
    p = Params()
    hyps = search(s.points_a, s.sizes_a, s.points_b, s.sizes_b, p.association).hypotheses
    v = verify_search(s.points_a, s.sizes_a, s.points_b, s.sizes_b, hyps, p.association, p.verification)
    truth = set(map(tuple, s.truth.tolist()))
    found = set(map(tuple, v.best.associations.tolist()))
    assert v.accepted and v.runner_up_support * 2 < v.support
    assert len(found & truth) >= 0.98 * len(found) and len(found) > 200


def test_candidates_near_a_tried_transform_are_those_of_the_one_by_one_test():
    """`_NearTried` decides for all later candidates at once which agree with a tried transform; the decisions
    are those of `_agree` on every candidate and every transform tried before it, also for candidates placed
    right at the gate (where the batched products' rounding could decide) and far from the origin (UTM)."""
    from sosmatch.plugin.chance import transforms_agree as _agree
    from sosmatch.plugin.verification import _NearTried

    rng = np.random.default_rng(3)
    for origin in (0.0, 5.0e6):
        pb = rng.uniform(-200, 200, (300, 3)) + [origin, origin, 0.0]
        base = Sim3(_yaw(20.0), np.array([3.0, -4.0, 1.0]))
        cands = []
        for _ in range(120):
            idx = rng.choice(300, int(rng.integers(0, 12)), replace=False)
            shift = np.r_[rng.uniform(-3, 3, 2), 0.0]
            cands.append((Sim3(_yaw(20.0 + rng.uniform(-0.5, 0.5)), base.translation + shift), idx))
        # one candidate exactly at the gate: its worst landmark lies 2.0 m from where `base` puts it
        cands.append((Sim3(base.rotation, base.translation + [2.0, 0.0, 0.0]), np.array([0, 1, 2])))
        tried = [base, cands[5][0]]
        near = _NearTried(cands, pb, 2.0)
        for t in tried:
            near.tried(-1, t)
        for k, (t, idx) in enumerate(cands):
            assert near.done[k] == any(_agree(t, x, pb[idx], 2.0) for x in tried)
        assert near.done[-1]


def test_the_chance_tail_follows_each_placements_opportunity():
    """Chance supports of placements that cover more or less of A (opportunity o_i uniform in 0-100, support
    Poisson with mean 0.1 o_i): the unconditioned negative binomial reads the spread of the overlaps as an
    unbounded gamma tail and overstates the probability of a support of 25 by orders of magnitude; with the
    opportunities the tail is that of the mixture the placements actually make."""
    from scipy import stats

    rng = np.random.default_rng(5)
    o = rng.uniform(0.0, 100.0, 512)
    x = rng.poisson(0.1 * o)
    truth = float(np.mean(stats.poisson.sf(24, 0.1 * np.linspace(0.0, 100.0, 100001))))
    free = chance_test(x, 25, 1.0)
    conditioned = chance_test(x, 25, 1.0, o)
    assert free.tail > 100 * truth
    assert truth / 5 < conditioned.tail < 5 * truth
    assert conditioned.overdispersion < 0.05  # what remains once the overlap is known is close to Poisson
    # a real extra spread at a given opportunity is kept: a fatter tail than the Poisson mixture
    spread = rng.negative_binomial(2.0, 2.0 / (2.0 + 0.1 * o))
    assert chance_test(spread, 25, 1.0, o).overdispersion > 0.2
    assert chance_test(spread, 25, 1.0, o).tail > 10 * conditioned.tail
    # no opportunity measured: the unconditioned model
    assert np.isnan(chance_test(x, 25, 1.0, np.zeros(512)).overdispersion)


def test_the_opportunity_counts_the_density_of_a_under_b_but_not_the_partners():
    from sosmatch.plugin.chance import chance_opportunity, horizontal_tree

    rng = np.random.default_rng(2)
    a = np.column_stack([rng.uniform(0, 200, (400, 2)), np.zeros(400)])
    tree = horizontal_tree(a)
    b = a[rng.choice(400, 60, replace=False)] + np.r_[rng.normal(0, 0.5, 2), 0.0]
    centred = chance_opportunity(tree, b, 3.0)
    half_off = chance_opportunity(tree, b + [100.0, 0.0, 0.0], 3.0)
    away = chance_opportunity(tree, b + [1000.0, 0.0, 0.0], 3.0)
    assert away == 0.0 and half_off < 0.75 * centred
    # B on its partners (a true alignment) or B shifted by 15 m over the same uniform field: alike, because the
    # density is counted beyond the gate
    shifted = chance_opportunity(tree, b + [15.0, 0.0, 0.0], 3.0)
    assert abs(centred - shifted) < 0.25 * shifted


def test_a_chance_alignment_counts_only_the_pairs_the_winner_does_not_explain():
    from sosmatch.plugin.chance import chance_pairs

    rng = np.random.default_rng(1)
    a = rng.uniform(0, 100, (50, 3))
    b = a.copy()
    pairs = np.column_stack([np.arange(10), np.arange(10)])  # the winner's own pairs (identity)
    wrong = np.column_stack([np.arange(10, 20), np.arange(20, 30)])  # pairs of landmarks the winner puts apart
    ident = Sim3(np.eye(3), np.zeros(3))
    far = np.linalg.norm(a[10:20] - b[20:30], axis=1) > 6.0
    assert chance_pairs(a, b, ident, np.vstack([pairs, wrong]), 3.0) == int(far.sum())
    assert chance_pairs(a, b, ident, pairs, 3.0) == 0


def test_an_early_stop_needs_the_whole_interval_past_it():
    """Chance supports with a real extra spread (negative binomial, k 1.5, over the opportunities): the first 16
    placements can miss the tail, so their point estimate calls a support of 16 a 1e-6 event among 1.6e5
    alignments while all 2048 placements say chance reaches it (p 1). The old early stop accepted there (p <=
    false_alarm x CHANCE_MARGIN after one batch); the bootstrap interval of those 16 under the dispersion they
    cannot exclude (the accepting stop's) reaches above that, so the test goes on. With many samples the interval
    closes around the point estimate."""
    from sosmatch.plugin.chance import dispersion_bound

    false_alarm, trials = 1e-2, 1.6e5
    fooled = 0
    for seed in range(40):
        rng = np.random.default_rng(seed)
        o = rng.uniform(0.5, 3.0, 2048)
        x = rng.negative_binomial(1.5, 1.5 / (1.5 + 0.8 * o))
        assert chance_test(x, 16, trials, o).p_value > 0.5
        first = chance_test(x[:16], 16, trials, o[:16]).p_value
        low, high = chance_interval(x[:16], 16, trials, o[:16])
        assert low <= first <= high
        if first <= false_alarm * CHANCE_MARGIN:
            fooled += 1
            bound = dispersion_bound(x[:16], o[:16])
            assert chance_interval(x[:16], 16, trials, o[:16], bound)[1] > false_alarm * CHANCE_MARGIN
    assert fooled >= 2
    # a clear chance case over many samples: a narrow interval that lies wholly past the refusal stop
    low, high = chance_interval(x, 16, trials, o)
    assert 0.5 <= low <= high


def test_the_dispersion_is_per_unit_of_mean_so_the_far_tail_follows_the_largest_opportunities():
    """Chance supports whose variance is 1.3 x their mean at every opportunity (pairs come in small clusters: a
    compound Poisson, as the seasons benchmark's chance samples are, var / mean 1.1-1.3 from means of 1 to 7),
    most placements over a sparse part of A and one in ten over its dense core. One 1/k for every mean (variance
    mu + mu^2 / k) is set by the small means' spread and puts it, squared, on the large ones: it overstated the
    probability of a support of 24 by 6x (median of 20 draws of 512); a dispersion per unit of mean recovers the
    tail within 2x and records phi = var / mean - 1."""
    from scipy import stats

    phi, beta = 0.3, 0.1

    def opportunities(rng, n):
        return np.where(rng.uniform(size=n) < 0.9, rng.uniform(2, 20, n), rng.uniform(40, 80, n))

    truth = float(np.mean(stats.nbinom.sf(23, beta * opportunities(np.random.default_rng(99), 400000) / phi,
                                          1 / (1 + phi))))
    tails, dispersions = [], []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        o = opportunities(rng, 512)
        x = rng.negative_binomial(beta * o / phi, 1 / (1 + phi))
        c = chance_test(x, 24, 1.0, o)
        tails.append(c.tail)
        dispersions.append(c.overdispersion)
    assert truth / 3 < np.median(tails) < 3 * truth
    assert 0.15 < np.median(dispersions) < 0.45


def test_a_dispersion_left_by_rounding_is_poisson_not_a_zero_tail():
    """rev27: supports whose moments agree to rounding (phi 1e-16) took the negative binomial branch, where
    1 / (1 + phi) is exactly 1 and the tail 0: p 0, any support accepted. Below MIN_OVERDISPERSION it is Poisson."""
    from scipy import stats

    x, o = np.array([3, 1, 3, 3]), np.array([0.1, 0.3, 1.1, 0.7])
    chance = chance_test(x, 8, 1e5, o)
    beta = (x.sum() + 1.0) / (o.sum() + o.sum() / len(x))
    assert chance.tail > 0 and chance.overdispersion == 0.0
    assert np.isclose(chance.tail, np.mean(stats.poisson.sf(7, beta * o)))
    assert chance.p_value > 0.5


def test_the_interval_leaves_out_resamples_without_opportunity():
    """rev27: a bootstrap resample drawn only from placements of zero opportunity had no rate, and its NaN made
    the whole interval NaN (the early stop never fired). Such resamples are left out."""
    x = np.array([0, 0, 0, 0, 0, 0, 0, 0, 0, 1])
    o = np.array([0.0] * 9 + [2.0])
    low, high = chance_interval(x, 6, 1e3, o)
    assert np.isfinite(low) and np.isfinite(high) and low <= high


def _nb1_placements(monkeypatch, phi):
    """`chance_refinements` replaced by an overdispersed chance source: each placement's support negative binomial
    with variance (1 + phi) x its mean 0.15 o, o uniform in 1-25, both fixed by where the placement puts B."""
    import sosmatch.plugin.chance as chance

    def refinements(pa, sa, pb, sb, winner, probe, gate, max_size, placements, *args):
        x, o = [], []
        for p in placements:
            rng = np.random.default_rng(int(np.abs(p.translation).sum() * 1e6) % 2**32)
            o.append(rng.uniform(1, 25))
            x.append(rng.negative_binomial(0.15 * o[-1] / phi, 1 / (1 + phi)))
        return np.asarray(x, np.int64), np.asarray(o)

    monkeypatch.setattr(chance, "chance_refinements", refinements)
    return refinements


def test_a_first_batch_that_looks_poisson_does_not_end_the_test(monkeypatch):
    """Chance supports with a spread of 1.25 x their mean (1.5e5 trials; a support of 19 is chance at p 0.002-0.05
    from 512 samples, by placement seed). Under seed 3 the first 16 samples happen to look Poisson (phi 0): the
    bootstrap of those 16 cannot show a spread they lack, and the test accepted there at p 1e-7 where its 512
    samples give 0.018. The accepting stop now assumes the dispersion the samples cannot exclude
    (`dispersion_bound`): no seed accepts on fewer samples what its 512 refuse, and a clear support (50) still
    stops after one or two batches."""
    import sosmatch.plugin.chance as chance

    refinements = _nb1_placements(monkeypatch, 0.25)
    rng = np.random.default_rng(0)
    a = np.column_stack([rng.uniform(0, 250, (300, 2)), np.zeros(300)])
    b = np.column_stack([rng.uniform(0, 200, (100, 2)), np.zeros(100)])
    ident = Sim3(np.eye(3), np.zeros(3))
    trials = effective_trials(a, b, 3.0)
    for seed in range(6):
        monkeypatch.setattr(chance, "CHANCE_SEED", seed)
        x, o = refinements(a, None, b, None, ident, b[:5], 3.0, 0.4, chance.chance_placements(a, b, 512))
        full = chance_test(x, 19, trials, o).p_value
        model, samples, _ = chance.sequential_chance(a, None, b, None, ident, b[:5], 19, 3.0, 0.4, 512, 0.01)
        if seed == 3:
            assert full > 0.01 and chance_test(x[:16], 19, trials, o[:16]).p_value < 1e-5  # the fooling batch
        assert model.p_value > 0.01 or full <= 0.01, (seed, len(samples), model.p_value, full)
        _, clear, _ = chance.sequential_chance(a, None, b, None, ident, b[:5], 50, 3.0, 0.4, 512, 0.01)
        assert len(clear) <= 2 * chance.CHANCE_BATCH


def test_the_dispersion_bound_covers_the_true_dispersion_and_shrinks_with_samples():
    """`dispersion_bound` on NB1 samples (phi 0.25) lies below the true phi in few draws (nominal 5 %) at 16 and
    at 256 samples, and is tighter with more; Poisson samples (phi 0) leave a large phi open after 16."""
    from sosmatch.plugin.chance import dispersion_bound

    bounds = {16: [], 256: []}
    poisson16 = []
    for seed in range(100):
        rng = np.random.default_rng(seed)
        o = rng.uniform(1, 25, 256)
        x = rng.negative_binomial(0.15 * o / 0.25, 1 / 1.25)
        for n in bounds:
            bounds[n].append(dispersion_bound(x[:n], o[:n]))
        poisson16.append(dispersion_bound(rng.poisson(0.15 * o[:16]), o[:16]))
    for n, got in bounds.items():
        assert np.mean(np.asarray(got) < 0.25) <= 0.1, n
    assert np.median(bounds[256]) < 0.7 < np.median(bounds[16])
    assert np.median(poisson16) > 0.5
    assert dispersion_bound(np.array([1, 2, 3]), None) == 0.0


def test_the_chance_test_is_one_of_the_pair_not_of_the_argument_order():
    """A map of a small area against one of a larger area: the chance test places the smaller over the larger
    whichever is given first (the winner inverted, its probe where the winner puts it), so `match A B` and `match
    B A` get the same samples, N_eff and p. Before, the samples were drawn over the first map: the suite's crossing
    pair gave p 0.003 one way and 1e-5 the other."""
    from sosmatch.plugin.chance import placed_map_is_a, sequential_chance

    rng = np.random.default_rng(4)
    large = np.column_stack([rng.uniform(0, 400, (500, 2)), rng.normal(0, 0.3, 500)])
    small = np.column_stack([rng.uniform(100, 220, (90, 2)), rng.normal(0, 0.3, 90)])
    a_from_b = Sim3(_yaw(40.0), np.array([15.0, -30.0, 0.0]))
    b_pts = a_from_b.inverse().apply(small)  # the small map in a frame of its own
    assert placed_map_is_a(b_pts, large) and not placed_map_is_a(large, b_pts)
    assert effective_trials(large, b_pts, 3.0) == effective_trials(b_pts, large, 3.0)
    probe = b_pts[:6]
    one, x1, o1 = sequential_chance(large, None, b_pts, None, a_from_b, probe, 9, 3.0, 0.4, 128, 0.01)
    two, x2, o2 = sequential_chance(b_pts, None, large, None, a_from_b.inverse(), a_from_b.apply(probe), 9, 3.0,
                                    0.4, 128, 0.01)
    assert np.array_equal(x1, x2) and np.allclose(o1, o2) and len(x1) >= 16
    assert one.p_value == two.p_value and one.trials == two.trials
