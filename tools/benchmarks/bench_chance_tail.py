"""The chance test's tail models side by side on many cached chance samples (issue 16, the verification side).

    nice -n 10 .venv/bin/python -m sosmatch.tools.benchmarks.bench_chance_tail --work W \
        [--maps MAPS --tag TAG --pair wA/SESSION:wB/SESSION ...] [--null PAIRS --null-starts M] [--seeds 8]

For each map pair (`--pair`, maps as bench_seasons leaves them, matched with `workflows.match.run` and default
parameters) or pair of unrelated random maps (`--null`: bench_negatives' `null_calibration` pairs, the best of M
random refinements offered as the winner), the arguments of the verification's `sequential_chance` are captured,
and B is refined from `--seeds` x 512 chance placements (`chance_placements` under CHANCE_SEED 0, 1, ...; the
winner's refinements left out as in the verification); their supports and opportunities are cached in
W/cache/NAME.npz (an existing cache is reused). Then each tail model (`MODELS`) is fitted on each seed's 512
samples: the p-value of the winner's support per seed (stability), and on the pooled samples the observed and
expected numbers of samples >= k (the far tail's goodness); on the null pairs M x q of the best of M starts
(calibration: below x in about a fraction x of the pairs).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from .machine import machine_summary

PLACEMENTS = 512  # per seed: as the verification's default chance_starts


def _captured(call: object) -> dict:
    """The run of `call()` with the verification's `sequential_chance` recorded (its last call's arguments)."""
    import sosmatch.plugin.verification as verification

    got: dict = {}
    real = verification.sequential_chance

    def spy(*args: object, **kwargs: object) -> object:
        got.clear()
        got.update(args=args, kwargs=kwargs)
        return real(*args, **kwargs)

    verification.sequential_chance = spy
    try:
        got["result"] = call()
    finally:
        verification.sequential_chance = real
    return got


def _draw(args: tuple, kwargs: dict, seeds: int) -> tuple[np.ndarray, np.ndarray]:
    """(seeds, <=512) supports and opportunities of the chance refinements under CHANCE_SEED 0..seeds-1 (rows
    padded with -1 where the winner's own refinements were left out)."""
    import sosmatch.plugin.chance as chance

    (pa, sa, pb, sb, winner, probe, support, gate, max_size, starts, false_alarm, prior_m, dof, z_weight) = args[:14]
    pairs, tree_a = kwargs.get("winner_pairs"), kwargs.get("tree_a")
    if chance.placed_map_is_a(pa, pb):  # the roles `sequential_chance` gives them
        pa, sa, pb, sb, winner, probe, pairs = chance.placed_over_b(pa, sa, pb, sb, winner, probe, pairs)
        tree_a = None
    xs, os_ = -np.ones((seeds, PLACEMENTS)), -np.ones((seeds, PLACEMENTS))
    tree_xy = chance.horizontal_tree(pa)
    saved = chance.CHANCE_SEED
    try:
        for s in range(seeds):
            chance.CHANCE_SEED = s
            placements = chance.chance_placements(pa, pb, PLACEMENTS, prior_m)
            x, o = chance.chance_refinements(pa, sa, pb, sb, winner, probe, gate, max_size, placements, dof,
                                             z_weight, pairs, tree_a, tree_xy)
            xs[s, :len(x)], os_[s, :len(o)] = x, o
    finally:
        chance.CHANCE_SEED = saved
    return xs, os_


def capture_pair(maps: Path, tag: str, a: str, b: str, work: Path, seeds: int) -> dict:
    """Match a pair of bench_seasons maps, cache the chance samples of its winner; returns the case."""
    from ...plugin.chance import effective_trials
    from ...plugin.params import Params
    from ...workflows.match import run
    from .bench_negatives import map_path

    name = f"{a.replace('/', '_')}--{b.replace('/', '_')}"
    cache = work / "cache" / f"{name}.npz"
    if cache.exists():
        return dict(np.load(cache, allow_pickle=True)["case"].item())
    out = work / "matches" / name
    got = _captured(lambda: run(Params(), map_path(maps, tag, a), map_path(maps, tag, b), out, plot=False,
                                overwrite=True))
    doc = json.loads((out / "match.json").read_text())
    ver = doc.get("verification") or {}
    case = {"name": name, "kind": "same" if a.split("/")[0] == b.split("/")[0] else "cross",
            "accepted": bool(got["result"].accepted), "support": ver.get("support_dof"),
            "runner_up": ver.get("runner_up_support"), "p_main": (ver.get("chance") or {}).get("p_value")}
    if "args" in got:
        args = got["args"]
        case["trials"] = effective_trials(args[0], args[2], args[7], args[11])
        case["x"], case["o"] = _draw(args, got["kwargs"], seeds)
    _save(cache, case)
    return case


def capture_null(seed: int, starts: int, work: Path, seeds: int) -> dict:
    """bench_negatives' null pair `seed` (the same maps, gate and best of `starts`), its chance samples cached."""
    from ...plugin.chance import effective_trials
    from ...plugin.verification import verify_alignments
    from .bench_negatives import null_pair

    cache = work / "cache" / f"null{seed}_{starts}.npz"
    if cache.exists():
        return dict(np.load(cache, allow_pickle=True)["case"].item())
    a, sa, b, sb, gate, best = null_pair(seed, starts)
    got = _captured(lambda: verify_alignments(a, sa, b, sb, [(best.transform, best.associations[:, 1])], gate,
                                              0.4, 6))
    v = got["result"]
    case = {"name": f"null{seed}", "kind": "null", "accepted": bool(v.accepted), "support": int(v.support),
            "runner_up": int(v.runner_up_support), "p_main": v.chance.p_value if v.chance else None,
            "starts": starts, "trials": effective_trials(a, b, gate)}
    if "args" in got:
        case["support"] = int(got["args"][6])
        case["x"], case["o"] = _draw(got["args"], got["kwargs"], seeds)
    _save(cache, case)
    return case


def _save(path: Path, case: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, case=np.array(case, dtype=object))
    os.replace(tmp, path)


# ---- the tail models: q(x, o, support) for one set of samples, and per-sample expected sf for the goodness ----

def _mu(x: np.ndarray, o: np.ndarray) -> np.ndarray:
    """Each placement's chance mean beta o_i, as the chance test takes it (`chance._placement_means`)."""
    from ...plugin.chance import _placement_means

    return _placement_means(np.asarray(x, np.float64)[None], np.asarray(o, np.float64)[None])[0]


def _nb_sf(k_minus_1: int, mu: np.ndarray, alpha: float) -> np.ndarray:
    from scipy import stats

    if alpha <= 0:
        return stats.poisson.sf(k_minus_1, mu)
    k = 1.0 / alpha
    return stats.nbinom.sf(k_minus_1, k, k / (k + mu))


def alpha_moments(x: np.ndarray, o: np.ndarray) -> float:
    mu = _mu(x, o)
    return float(max(0.0, np.sum((x - mu) ** 2 - mu) / np.sum(mu**2)))


def alpha_ml(x: np.ndarray, o: np.ndarray) -> float:
    """The maximum-likelihood dispersion of the NB with offset mean beta o_i (0 at the boundary)."""
    from scipy.optimize import minimize_scalar
    from scipy.special import gammaln

    mu = _mu(x, o)

    def nll(log_alpha: float) -> float:
        al = np.exp(log_alpha)
        k = 1.0 / al
        return -float(np.sum(gammaln(x + k) - gammaln(k) + k * np.log(k / (k + mu)) + x * np.log(mu / (k + mu))))

    pois = -float(np.sum(x * np.log(mu) - mu - gammaln(x + 1)))
    r = minimize_scalar(nll, bounds=(np.log(1e-6), np.log(20.0)), method="bounded")
    return float(np.exp(r.x)) if r.fun < pois - 1e-9 else 0.0


def phi_moments(x: np.ndarray, o: np.ndarray) -> float:
    """The NB1 dispersion (variance (1 + phi) mu) by moments: what `chance._opportunity_tails` fits (its own
    estimate, so the goodness table and the stability columns measure one model on any checkout; rev27)."""
    from ...plugin.chance import _opportunity_tails

    return float(_opportunity_tails(np.asarray(x, np.float64)[None], np.asarray(o, np.float64)[None], 1)[1][0])


def phi_ml(x: np.ndarray, o: np.ndarray) -> float:
    """The NB1 dispersion by maximum likelihood (size mu_i / phi; 0 at the boundary)."""
    from scipy import stats
    from scipy.optimize import minimize_scalar

    mu = _mu(x, o)

    def nll(log_phi: float) -> float:
        phi = np.exp(log_phi)
        return -float(np.sum(stats.nbinom.logpmf(x, mu / phi, 1.0 / (1.0 + phi))))

    r = minimize_scalar(nll, bounds=(np.log(1e-4), np.log(5.0)), method="bounded")
    return float(np.exp(r.x)) if r.fun < -float(np.sum(stats.poisson.logpmf(x, mu))) else 0.0


def model_sf(name: str, x: np.ndarray, o: np.ndarray, ks: np.ndarray, at_o: np.ndarray | None = None) -> np.ndarray:
    """Per evaluated placement (at_o: their opportunities, default o) and per k: P(X >= k) under model `name`
    fitted on (x, o)."""
    from scipy import stats

    mu_fit = _mu(x, o)
    scale = mu_fit.sum() / max(o.sum(), 1e-12)
    mu = np.maximum(scale * (o if at_o is None else at_o), 1e-9)
    if name == "poisson-mix":
        return stats.poisson.sf(ks[None, :] - 1, mu[:, None])
    if name.startswith("nb1"):
        phi = phi_moments(x, o) if name == "nb1-moments" else phi_ml(x, o)
        if phi <= 0:
            return stats.poisson.sf(ks[None, :] - 1, mu[:, None])
        return stats.nbinom.sf(ks[None, :] - 1, mu[:, None] / phi, 1.0 / (1.0 + phi))
    if name == "nb-moments":
        al = alpha_moments(x, o)
    elif name == "nb-ml":
        al = alpha_ml(x, o)
    else:
        raise ValueError(name)
    return _nb_sf(ks[None, :] - 1, mu[:, None], al)


MODELS = ("nb-moments", "poisson-mix", "nb-ml", "nb1-ml", "nb1-moments")


def q_of(name: str, x: np.ndarray, o: np.ndarray, support: int) -> float:
    """One chance alignment's tail at `support` under model `name` fitted on (x, o); "nb1-moments" is the
    verification's own (`chance.chance_test`: on a checkout with another chance model, that model)."""
    if name == "nb1-moments":
        from ...plugin.chance import chance_test

        return chance_test(x, support, 1.0, o).tail
    return float(np.mean(model_sf(name, x, o, np.array([support]))[:, 0]))


def best_of(q: float, trials: float) -> float:
    return float(-np.expm1(trials * np.log1p(-min(q, 1 - 1e-16))))


def _rows(case: dict) -> list[tuple[np.ndarray, np.ndarray]]:
    out = []
    for xr, orow in zip(case["x"], case["o"], strict=True):
        keep = xr >= 0
        out.append((xr[keep], orow[keep]))
    return out


def report(cases: list[dict]) -> str:
    lines = []
    # stability: p per seed at the winner's support
    lines.append("| case | support / runner-up | main p (match) | " + " | ".join(
        f"{m}: p over seeds (median, min-max)" for m in MODELS) + " | " + " | ".join(
        f"{m} dispersion (min-max)" for m in ("nb-moments", "nb-ml", "nb1-ml", "nb1-moments")) + " |")
    lines.append("|---|---|---|" + "---|" * (len(MODELS) + 4))
    for c in cases:
        if "x" not in c:
            lines.append(f"| {c['name']} | {c['support']} / {c['runner_up']} | - | no chance test |")
            continue
        rows = _rows(c)
        cells = []
        for m in MODELS:
            ps = [best_of(q_of(m, x, o, c["support"]), c["trials"]) for x, o in rows]
            cells.append(f"{np.median(ps):.2g} ({min(ps):.2g}-{max(ps):.2g})")
        for fn in (alpha_moments, alpha_ml, phi_ml, phi_moments):
            al = [fn(x, o) for x, o in rows]
            cells.append(f"{min(al):.3f}-{max(al):.3f}")
        p_main = "-" if c["p_main"] is None else f"{c['p_main']:.2g}"
        lines.append(f"| {c['name']} | {c['support']} / {c['runner_up']} | {p_main} | " + " | ".join(cells) + " |")
    # the far tail: pooled over every case's seeds, each seed's 512 fitted alone, expected counts >= k
    ks = np.arange(4, 31)
    obs = np.zeros(len(ks))
    exp = {m: np.zeros(len(ks)) for m in MODELS}
    for c in cases:
        if "x" not in c:
            continue
        for x, o in _rows(c):
            obs += (x[:, None] >= ks[None, :]).sum(axis=0)
            for m in MODELS:
                exp[m] += model_sf(m, x, o, ks).sum(axis=0)
    lines.append("")
    lines.append("| samples >= k | observed | " + " | ".join(MODELS) + " |")
    lines.append("|---|---|" + "---|" * len(MODELS))
    for i, k in enumerate(ks):
        if obs[i] == 0 and all(exp[m][i] < 0.5 for m in MODELS):
            break
        lines.append(f"| {k} | {int(obs[i])} | " + " | ".join(f"{exp[m][i]:.1f}" for m in MODELS) + " |")
    # the null: M q of the best of M, per model, fitted on seed 0 (the verification's own placements)
    nulls = [c for c in cases if c["kind"] == "null" and "x" in c]
    if nulls:
        lines.append("")
        lines.append("| null: M q below | " + " | ".join(MODELS) + " |")
        lines.append("|---|" + "---|" * len(MODELS))
        mq = {m: [] for m in MODELS}
        for c in nulls:
            for m in MODELS:
                x, o = _rows(c)[0]
                mq[m].append(c["starts"] * q_of(m, x, o, c["support"]))
        for lim in (0.01, 0.05, 0.2, 0.5):
            lines.append(f"| {lim} ({lim * len(nulls):.1f} expected of {len(nulls)}) | "
                         + " | ".join(str(int(np.sum(np.asarray(mq[m]) < lim))) for m in MODELS) + " |")
        lines.append("| p <= 0.01 (accepted by chance) | " + " | ".join(
            str(sum(best_of(q_of(m, *_rows(c)[0], c["support"]), c["trials"]) <= 0.01 for c in nulls))
            for m in MODELS) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--maps", type=Path)
    ap.add_argument("--tag", default="main")
    ap.add_argument("--pair", action="append", default=[], help="wA/SESSION:wB/SESSION")
    ap.add_argument("--null", type=int, default=0)
    ap.add_argument("--null-first", type=int, default=0)
    ap.add_argument("--null-starts", type=int, default=3000)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--report-only", action="store_true", help="only the cached cases")
    args = ap.parse_args(argv)
    print(machine_summary(), flush=True)
    cases = []
    if args.report_only:
        for f in sorted((args.work / "cache").glob("*.npz")):
            cases.append(dict(np.load(f, allow_pickle=True)["case"].item()))
    for spec in args.pair:
        a, b = spec.split(":")
        cases.append(capture_pair(args.maps, args.tag, a, b, args.work, args.seeds))
        print(f"{spec}: support {cases[-1]['support']} runner-up {cases[-1]['runner_up']} p {cases[-1]['p_main']}",
              flush=True)
    for s in range(args.null_first, args.null_first + args.null):
        cases.append(capture_null(s, args.null_starts, args.work, args.seeds))
        print(f"null {s}: support {cases[-1]['support']} p {cases[-1]['p_main']}", flush=True)
    print(report(cases))
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
