"""Data association for the EKF: individual gating and bounded JCBB (numpy only).

Joint Compatibility Branch and Bound (Neira & Tardos 2001): among the
hypotheses that pair observations of one scan with map landmarks (each
landmark used at most once, an observation may stay unpaired), pick the one
with the most pairings whose *joint* innovation is compatible, i.e. whose
joint normalised innovation squared ``nu^T C^-1 nu`` lies below the chi-square
quantile with ``2 k`` degrees of freedom (k pairings, 2-D measurements); ties
are broken by the lower joint NIS. Correlations between the innovations of
different pairings (through the shared robot pose and map) are what lets it
reject pairings that individual gating accepts one by one.

Bounds (JCBB is exponential in the number of observations in the worst case):

- each observation keeps at most ``max_candidates`` individually compatible
  landmarks (the closest in Mahalanobis distance), so the tree has at most
  ``(max_candidates + 1) ** m`` leaves;
- the search visits at most ``max_nodes`` pairing tests; when the budget runs
  out the search stops and the best hypothesis found so far is returned;
- the search starts from a greedy nearest-neighbour hypothesis that is itself
  jointly compatible (observations in increasing order of their best
  individual distance, each takes its closest unused landmark if the joint
  test still passes), so the result is never worse than that fallback, and
  the branch-and-bound prunes against it from the first node.

Each pairing test solves one dense system of size ``2 k <= 2 m``, so the
worst-case cost is ``O(max_nodes * m^3)`` flops on tiny matrices.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from slamcore import chi2
from slamcore.planar import geometry as models


@lru_cache(maxsize=512)
def chi2_quantile(prob: float, dof: int) -> float:
    """Chi-square quantile; cached because JCBB asks for the same few per scan."""
    if dof <= 0:
        raise ValueError(f"dof must be positive, got {dof}")
    if not 0.0 < prob < 1.0:
        raise ValueError(f"prob must be in (0, 1), got {prob}")
    return chi2.ppf(prob, dof)


def t2_quantile(prob: float, dof: float) -> float:
    """Quantile of the squared Mahalanobis distance of a 2-D Student-t error with ``dof``
    degrees of freedom (``inf``: Gaussian, the chi-square quantile with 2 dof).

    Closed form: for the bivariate t, ``P(d2 <= x) = 1 - (1 + x / dof)^(-dof / 2)``
    (``d2 / 2`` is F(2, dof)); the Gaussian's ``1 - exp(-x / 2)`` is its limit.
    """
    if not 0.0 < prob < 1.0:
        raise ValueError(f"prob must be in (0, 1), got {prob}")
    if not dof > 0.0:
        raise ValueError(f"dof must be positive, got {dof}")
    if math.isinf(dof):
        return -2.0 * math.log1p(-prob)
    try:
        return dof * math.expm1(-2.0 / dof * math.log1p(-prob))
    except OverflowError:  # dof far below 1: beyond float64, as good as no gate
        return math.inf


def confirming_sightings(gate_prob: float, dof: float) -> int:
    """Sightings that confirm a new landmark under a sensor whose errors are Student-t
    with ``dof`` degrees of freedom (``inf``: Gaussian).

    A sighting of a mapped landmark falls outside its association gate (the Gaussian
    quantile of ``gate_prob``) with probability ``q`` (:func:`t2_quantile`'s
    distribution), and is then evidence of a landmark that is not there. The fewest
    ``n`` with ``q^n <= 1 - gate_prob`` makes ``n`` such sightings in a row as rare as
    the gate's own error: 1 for a Gaussian sensor (``q = 1 - gate_prob``), 3 for
    MRCLAM's camera (5.1 dof at 0.999: ``q = 0.035``).
    """
    if not 0.0 < gate_prob < 1.0:
        raise ValueError(f"gate_prob must be in (0, 1), got {gate_prob}")
    if not dof > 0.0:
        raise ValueError(f"dof must be positive, got {dof}")
    if math.isinf(dof):
        return 1
    gate = t2_quantile(gate_prob, math.inf)
    log_q = -0.5 * dof * math.log1p(gate / dof)  # log P(d2 > gate) under the t
    return max(1, math.ceil(math.log1p(-gate_prob) / log_q - 1e-9))


def ambiguous_pairings(
    chosen: list[int | None],
    pair_obs: np.ndarray,
    pair_landmark: np.ndarray,
    joint_covariance: np.ndarray,
    nu: np.ndarray,
    apart: np.ndarray,
    *,
    chi2_prob: float,
    max_nodes: int,
) -> list[bool]:
    """Per observation, whether its pairing in ``chosen`` was left to the pose prior:
    another jointly compatible hypothesis pairs the same observations and gives this one
    a landmark the sensor tells apart from the chosen one.

    Args:
        chosen: per observation, the index of its chosen pair or None.
        pair_obs, pair_landmark: (P,) every individually compatible pair.
        joint_covariance: (2P, 2P) the pairs' innovations' joint covariance.
        nu: (P, 2) the pairs' innovations.
        apart: (P,) whether pair p's landmark is told apart from the landmark chosen
            for p's observation (False for an unpaired observation's pairs).
        chi2_prob: the joint test's probability (chi-square, 2k dof).
        max_nodes: budget of joint tests; a search that runs out of it has not shown
            any pairing to be the only one, and every chosen pairing is held.

    Depth-first over the hypotheses that pair exactly the chosen observations, each
    landmark at most once, pruned by joint compatibility as JCBB prunes.
    """
    held = [False] * len(chosen)
    obs = [i for i, p in enumerate(chosen) if p is not None]
    if not obs or not np.any(apart):
        return held
    options = {i: np.flatnonzero(pair_obs == i).tolist() for i in obs}
    budget = max_nodes

    def compatible(pairs: list[int]) -> bool:
        rows = np.array([[2 * x, 2 * x + 1] for x in pairs]).reshape(-1)
        v = nu[pairs].reshape(-1)
        d2 = float(v @ np.linalg.solve(joint_covariance[np.ix_(rows, rows)], v))
        return d2 <= chi2_quantile(chi2_prob, 2 * len(pairs))

    def visit(pairs: list[int], used: set[int]) -> bool:
        """False when the budget ran out."""
        nonlocal budget
        if len(pairs) == len(obs):
            for i, q in zip(obs, pairs, strict=True):
                held[i] = held[i] or bool(apart[q])
            return True
        for q in options[obs[len(pairs)]]:
            if int(pair_landmark[q]) in used:
                continue
            if budget == 0:
                return False
            budget -= 1
            if compatible(pairs + [q]) and not visit(pairs + [q], used | {int(pair_landmark[q])}):
                return False
        return True

    if not visit([], set()):
        return [p is not None for p in chosen]
    return held


def mahalanobis_sq_2d(nu: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``nu^T S^-1 nu`` for batches of 2-vectors (..., 2) and 2x2 matrices (..., 2, 2)."""
    a, b, c, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 0], S[..., 1, 1]
    det = a * d - b * c
    x, y = nu[..., 0], nu[..., 1]
    return (d * x * x - (b + c) * x * y + a * y * y) / det


def individual_candidates(d2: np.ndarray, gate: float, max_candidates: int) -> list[list[int]]:
    """Per observation, the landmark indices with ``d2 < gate``, closest first, at most ``max_candidates``.

    Args:
        d2: (m, L) squared Mahalanobis distances of observation i to landmark l.
    """
    out: list[list[int]] = []
    for row in np.asarray(d2):
        ok = np.flatnonzero(row < gate)
        ok = ok[np.argsort(row[ok], kind="stable")][:max_candidates]
        out.append([int(j) for j in ok])
    return out


@dataclass(frozen=True)
class JcbbResult:
    """Outcome of :func:`jcbb`.

    Attributes:
        hypothesis: per observation, the landmark index (as given in
            ``pair_landmark``) or ``None``.
        pairs: per observation, the index of the chosen candidate pair or ``None``.
        joint_nis: joint NIS of the chosen pairings (0 when none).
        nodes: pairing tests done.
        budget_exhausted: the node budget stopped the search early.
    """

    hypothesis: list[int | None]
    pairs: list[int | None]
    joint_nis: float
    nodes: int
    budget_exhausted: bool


def jcbb(
    z: np.ndarray,
    z_pred: np.ndarray,
    joint_covariance: np.ndarray,
    pair_obs: np.ndarray,
    pair_landmark: np.ndarray,
    *,
    chi2_prob: float = 0.99,
    max_nodes: int = 2000,
    individual_d2: np.ndarray | None = None,
    pair_gain: np.ndarray | None = None,
    noise_logdet: np.ndarray | None = None,
    pair_ambiguous: np.ndarray | None = None,
) -> JcbbResult:
    """Joint-compatibility branch and bound over candidate (observation, landmark) pairs.

    Args:
        z: (m, 2) observations ``[range_m, bearing_rad]`` of one scan.
        z_pred: (P, 2) predicted measurement of each candidate pair.
        joint_covariance: (2P, 2P) covariance of the stacked innovations of all
            pairs, ``H P H^T + R`` (R only on a pair's own diagonal block).
            Blocks between two pairs of the same observation are never used.
        pair_obs: (P,) observation index of each pair; candidates of one
            observation should be listed closest first (they are tried in order).
        pair_landmark: (P,) landmark index of each pair.
        chi2_prob: joint compatibility probability (chi-square, 2k dof).
        max_nodes: budget of pairing tests (see the module docstring).
        individual_d2: (P,) individual distances, used to order the greedy
            fallback; computed from the diagonal blocks when omitted.
        pair_gain: (P,) None (default) maximises the number of pairings (ties:
            lower joint NIS). Given, the search maximises the likelihood
            objective of :class:`_LikelihoodSearch` instead, ``pair_gain[p]``
            being the log-odds constant of pairing p rather than starting a
            new landmark (e.g. ``log(P_D / (1 - P_D)) - log(density_z)``).
        noise_logdet: (m,) ``log det(2 pi R_i)`` of each observation's noise;
            required with ``pair_gain`` (it bounds the search).
        pair_ambiguous: (P,) bool, with ``pair_gain`` only: pairings whose gate
            cannot tell the landmark from a new one on its own; a hypothesis
            holding exactly one of them is refused (see :class:`_LikelihoodSearch`).

    Returns:
        :class:`JcbbResult`.
    """
    z = np.asarray(z, dtype=float).reshape(-1, 2)
    m = z.shape[0]
    pair_obs = np.asarray(pair_obs, dtype=np.int64).reshape(-1)
    pair_landmark = np.asarray(pair_landmark, dtype=np.int64).reshape(-1)
    n_pairs = pair_obs.size
    C = np.asarray(joint_covariance, dtype=float)
    if C.shape != (2 * n_pairs, 2 * n_pairs):
        raise ValueError(f"joint_covariance must be {(2 * n_pairs,) * 2}, got {C.shape}")
    nu = (
        models.innovation(z[pair_obs], np.asarray(z_pred, dtype=float).reshape(-1, 2))
        if n_pairs
        else np.zeros((0, 2))
    )
    if individual_d2 is None:
        blocks = (
            np.stack([C[2 * p : 2 * p + 2, 2 * p : 2 * p + 2] for p in range(n_pairs)])
            if n_pairs
            else np.zeros((0, 2, 2))
        )
        individual_d2 = mahalanobis_sq_2d(nu, blocks)

    cands: list[list[int]] = [[] for _ in range(m)]
    for p in range(n_pairs):
        cands[int(pair_obs[p])].append(p)
    if pair_gain is None:
        search = _JcbbSearch(C, nu.reshape(-1), cands, pair_landmark, chi2_prob, max_nodes)
    else:
        if noise_logdet is None:
            raise ValueError("jcbb: pair_gain needs noise_logdet")
        ambiguous = (
            np.zeros(n_pairs, dtype=bool)
            if pair_ambiguous is None
            else np.asarray(pair_ambiguous, dtype=bool).reshape(-1)
        )
        search = _LikelihoodSearch(
            C,
            nu.reshape(-1),
            cands,
            pair_landmark,
            chi2_prob,
            max_nodes,
            np.asarray(pair_gain, dtype=float).reshape(-1),
            np.asarray(noise_logdet, dtype=float).reshape(-1),
            ambiguous,
        )
    best_pairs, best_nis, exhausted = search.run(individual_d2)

    per_obs_pair: list[int | None] = [None] * m
    for p in best_pairs:
        per_obs_pair[int(pair_obs[p])] = int(p)
    hyp = [None if p is None else int(pair_landmark[p]) for p in per_obs_pair]
    return JcbbResult(hyp, per_obs_pair, float(best_nis), search.nodes, exhausted)


class _Budget(Exception):
    """The node budget of :func:`jcbb` ran out."""


class _JcbbSearch:
    """The branch and bound of :func:`jcbb` over one scan's candidate pairs.

    ``C`` (2P, 2P) and ``nu_flat`` (2P,): joint covariance and stacked
    innovations of the P pairs; ``cands[i]``: pair indices of observation i,
    tried in order; ``pair_landmark`` (P,): landmark of each pair. Holds the
    best hypothesis found so far (pair indices) and the pairing tests done.
    """

    def __init__(
        self,
        C: np.ndarray,
        nu_flat: np.ndarray,
        cands: list[list[int]],
        pair_landmark: np.ndarray,
        chi2_prob: float,
        max_nodes: int,
    ):
        self.C = C
        self.nu_flat = nu_flat
        self.cands = cands
        self.order = [i for i in range(len(cands)) if cands[i]]  # observations with candidates
        self.pair_landmark = pair_landmark
        self.chi2_prob = chi2_prob
        self.max_nodes = max_nodes
        self.best_pairs: list[int] = []
        self.best_nis = 0.0
        self.nodes = 0

    def run(self, individual_d2: np.ndarray) -> tuple[list[int], float, bool]:
        """Best pairs, their joint NIS and whether the budget stopped the search early."""
        self.best_pairs = self.greedy(individual_d2)
        self.best_nis = self.joint_nis(self.best_pairs)
        try:
            self.search(0, [], set())
        except _Budget:
            return self.best_pairs, self.best_nis, True
        return self.best_pairs, self.best_nis, False

    def joint_nis(self, pairs: list[int]) -> float:
        """``nu^T C^-1 nu`` over ``pairs`` (inf when their covariance is not positive definite)."""
        if not pairs:
            return 0.0
        rows = np.array([[2 * p, 2 * p + 1] for p in pairs]).reshape(-1)
        Cs = self.C[np.ix_(rows, rows)]
        v = self.nu_flat[rows]
        try:
            L = np.linalg.cholesky(Cs)
        except np.linalg.LinAlgError:
            return math.inf
        y = np.linalg.solve(L, v)
        return float(y @ y)

    def compatible(self, pairs: list[int]) -> tuple[bool, float]:
        """Joint NIS of ``pairs`` below the chi-square quantile with ``2 len(pairs)`` dof, and the NIS."""
        nis = self.joint_nis(pairs)
        return nis <= chi2_quantile(self.chi2_prob, 2 * len(pairs)), nis

    def greedy(self, individual_d2: np.ndarray) -> list[int]:
        """Greedy nearest-neighbour start: jointly compatible by construction.

        Observations in increasing order of their best individual distance,
        each takes its closest unused landmark if the joint test still passes.
        """
        greedy: list[int] = []
        used: set[int] = set()
        cands = self.cands
        best_d = {i: min(individual_d2[p] for p in cands[i]) for i in self.order}
        for i in sorted(self.order, key=lambda i: best_d[i]):
            for p in sorted(cands[i], key=lambda p: individual_d2[p]):
                if int(self.pair_landmark[p]) in used:
                    continue
                ok, _ = self.compatible(greedy + [p])
                if ok:
                    greedy.append(p)
                    used.add(int(self.pair_landmark[p]))
                    break
        return greedy

    def branches(self, i: int, used_lm: set[int]) -> Iterator[int]:
        """Candidate pairs of observation ``i`` whose landmark no chosen pair holds, each
        counted as a node (:class:`_Budget` past ``max_nodes``). A pair's landmark stays in
        ``used_lm`` until the caller asks for the next pair, so the branch searched below
        the pair cannot pair that landmark again."""
        for p in self.cands[i]:
            lm = int(self.pair_landmark[p])
            if lm in used_lm:
                continue
            self.nodes += 1
            if self.nodes > self.max_nodes:
                raise _Budget
            used_lm.add(lm)
            yield p
            used_lm.discard(lm)

    def search(self, level: int, chosen: list[int], used_lm: set[int]) -> None:
        """Depth-first over ``order[level:]``: pair observation ``order[level]`` with each
        compatible unused candidate, then leave it unpaired; prune branches that
        cannot beat the best pairing count. Raises :class:`_Budget` past ``max_nodes``."""
        order = self.order
        if level == len(order):
            nis = self.joint_nis(chosen)
            if len(chosen) > len(self.best_pairs) or (
                len(chosen) == len(self.best_pairs) and nis < self.best_nis
            ):
                self.best_pairs, self.best_nis = list(chosen), nis
            return
        remaining = len(order) - level - 1  # levels after this one
        i = order[level]
        if len(chosen) + 1 + remaining >= len(self.best_pairs):
            for p in self.branches(i, used_lm):
                if self.compatible(chosen + [p])[0]:
                    self.search(level + 1, chosen + [p], used_lm)
        if len(chosen) + remaining >= len(self.best_pairs):  # the "leave unpaired" branch
            self.search(level + 1, chosen, used_lm)


class _LikelihoodSearch(_JcbbSearch):
    """JCBB maximising the likelihood of the scan instead of the pairing count.

    Maximum-likelihood association with a density of new features (Cox &
    Leonard 1994; the track score of Blackman & Popoli 1999, ch. 6): among
    jointly compatible hypotheses H, maximise

        score(H) = sum_{p in H} gain_p - NIS_H / 2 - log det(2 pi C_H) / 2,

    the log-likelihood ratio of H against "every observation is a new landmark",
    where ``gain_p = log(P_D / (1 - P_D)) - log(lambda_i)`` weighs detecting a
    mapped landmark against a new one at observation i's density ``lambda_i``.
    Counting pairings rewards a pairing that is barely compatible as much as a
    good one: a first sighting inside a wide gate of a landmark mapped long ago
    is accepted as soon as it is jointly compatible; here it must also explain
    the observation better than a new landmark would.

    Bound: adding pair p to a hypothesis adds ``gain_p - dNIS/2 - log det(2 pi
    S_p|H)/2`` with ``dNIS >= 0`` and the conditional covariance ``S_p|H >=
    R_i`` (the observation's own noise), so a branch cannot gain more than
    ``max_p max(0, gain_p - log det(2 pi R_i) / 2)`` per remaining observation.
    The bound holds for every extension, so it also prunes under the support
    rule below.

    Support rule: a pairing marked ``ambiguous`` (by the caller: e.g. its gate
    is so wide that a new landmark is expected inside it about as often as the
    mapped one, the re-observation of a landmark mapped long ago across a
    drifted pose, and the measurement alone does not decide) is accepted only
    in a hypothesis holding at least one other ambiguous pairing. Joint
    compatibility is a test only between pairings whose
    innovations are correlated: a recently mapped landmark moves with the
    robot and lends no support to a loop-closing pairing, while two wide-gate
    pairings of one loop share the pose error, so their joint test checks
    their relative geometry (Neira & Tardos 2001: the probability that
    spurious pairings are jointly compatible falls with their number; a
    single one is not a hypothesis to close a loop on).
    """

    def __init__(
        self, C, nu_flat, cands, pair_landmark, chi2_prob, max_nodes, pair_gain, noise_logdet, ambiguous
    ):
        super().__init__(C, nu_flat, cands, pair_landmark, chi2_prob, max_nodes)
        self.gain = pair_gain
        self.ambiguous = ambiguous
        # per observation with candidates, the most one pairing can add
        bound = [max(0.0, max(pair_gain[p] - 0.5 * noise_logdet[i] for p in cands[i])) for i in self.order]
        #: tail[k]: the most the observations order[k:] can still add
        self.tail = np.concatenate([np.cumsum(bound[::-1])[::-1], [0.0]])
        self.best_score = 0.0

    def score(self, pairs: list[int]) -> tuple[bool, float, float]:
        """Joint compatibility, score and joint NIS of ``pairs``."""
        if not pairs:
            return True, 0.0, 0.0
        rows = np.array([[2 * p, 2 * p + 1] for p in pairs]).reshape(-1)
        try:
            L = np.linalg.cholesky(self.C[np.ix_(rows, rows)])
        except np.linalg.LinAlgError:
            return False, -math.inf, math.inf
        y = np.linalg.solve(L, self.nu_flat[rows])
        nis = float(y @ y)
        logdet = 2.0 * float(np.sum(np.log(np.diag(L)))) + len(rows) * math.log(2 * math.pi)
        ok = nis <= chi2_quantile(self.chi2_prob, 2 * len(pairs))
        return ok, float(sum(self.gain[p] for p in pairs)) - 0.5 * nis - 0.5 * logdet, nis

    def supported(self, pairs: list[int]) -> bool:
        """The support rule: not exactly one ambiguous pairing."""
        return int(np.count_nonzero(self.ambiguous[pairs])) != 1 if pairs else True

    def run(self, individual_d2: np.ndarray) -> tuple[list[int], float, bool]:
        greedy = self.greedy(individual_d2)
        if not self.supported(greedy):  # drop its lone ambiguous pairing
            greedy = [p for p in greedy if not self.ambiguous[p]]
        self.best_pairs = greedy
        ok, self.best_score, self.best_nis = self.score(greedy)
        if not ok or self.best_score < 0.0:  # every observation new scores 0
            self.best_pairs, self.best_score, self.best_nis = [], 0.0, 0.0
        try:
            self.search_score(0, [], set(), 0.0)
        except _Budget:
            return self.best_pairs, self.best_nis, True
        return self.best_pairs, self.best_nis, False

    def search_score(self, level: int, chosen: list[int], used_lm: set[int], current: float) -> None:
        """Depth-first as :meth:`_JcbbSearch.search`, pruned by the score bound."""
        if current > self.best_score and self.supported(chosen):
            self.best_pairs, self.best_score = list(chosen), current
            self.best_nis = self.score(chosen)[2]
        if level == len(self.order) or current + self.tail[level] <= self.best_score:
            return
        for p in self.branches(self.order[level], used_lm):
            ok, s, _ = self.score(chosen + [p])
            if ok:
                self.search_score(level + 1, chosen + [p], used_lm, s)
        self.search_score(level + 1, chosen, used_lm, current)
