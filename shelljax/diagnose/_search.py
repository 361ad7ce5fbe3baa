"""The search over combinations of model terms, its out-of-sample scoring and its averaging: one
code for the diagnosis's effects and the rig's terms (``shelljax.rig`` borrows it through
``diagnose.internal``).

**Scoring.** Every model is scored by its pointwise leave-one-trial-out elpd (one value per
trial); two models are compared by the sum of the paired differences, Δ, and its standard error
√n · sd(differences).

**Forward search.** From a start model, every child (the model plus one term the caller allows)
is fitted, each from its parent's optimum. The best-scoring child that *clears* its parent becomes
the current model, and its children are fitted in turn, until no child clears or the size limit is
reached. The diagnosis clears by its decision margin (Δ ≥ 4 nats and ≥ 2 SE), so singles are
ranked, the best winner is expanded to pairs, then triples; the rig clears by any gain (Δ > 0),
so a pair is reached where neither term alone wins by the margin.

**Averaging.** Pseudo-BMA+ (Yao et al. 2018): Bayesian-bootstrap Akaike weights of the models'
pointwise elpd.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np

BOOTSTRAP_DRAWS = 2000  # Bayesian-bootstrap draws of pseudo-BMA+


def elpd_difference(better: np.ndarray, worse: np.ndarray) -> tuple[float, float]:
    """(Δ elpd [nats], its standard error [nats]) of two models' pointwise elpd (one value per trial)."""
    diff = np.asarray(better) - np.asarray(worse)
    return float(diff.sum()), float(math.sqrt(diff.size * np.var(diff)))


@dataclasses.dataclass(frozen=True)
class Margin:
    """When one model predicts better than another: Δ elpd ≥ ``nats`` and Δ ≥ ``se`` standard errors,
    or, with ``nats`` = 0 and ``se`` = 0, Δ > 0 (any gain)."""

    nats: float
    se: float

    def beats(self, better: np.ndarray, worse: np.ndarray) -> tuple[bool, float, float]:
        """(whether ``better`` beats ``worse`` by the margin, Δ [nats], its SE [nats])."""
        delta, se = elpd_difference(better, worse)
        if self.nats == 0 and self.se == 0:
            return float(np.sum(better)) > float(np.sum(worse)), delta, se
        return delta >= self.nats and delta >= self.se * se, delta, se


ANY_GAIN = Margin(0.0, 0.0)


@dataclasses.dataclass(frozen=True)
class SearchResult:
    """What :func:`forward_search` fitted: ``fitted`` (every converged model by its terms, in the order
    fitted), ``failed`` ({terms, message} of the fits that failed), ``path`` (the models the search
    moved through, start first: the last is the chosen one) and ``children`` (the terms of the
    chosen model's children that were fitted: its expansions, which did not clear it)."""

    fitted: dict
    failed: list[dict]
    path: list[tuple[str, ...]]
    children: list[tuple[str, ...]]

    @property
    def chosen(self) -> tuple[str, ...]:
        return self.path[-1]


def forward_search(
    start: tuple[str, ...],
    start_result,
    children: Callable[[tuple[str, ...]], Sequence[tuple[str, ...]]],
    fit: Callable[[tuple[str, ...], tuple[str, ...]], object],
    elpd: Callable[[object], np.ndarray],
    margin: Margin,
    max_terms: int | None = None,
) -> SearchResult:
    """Forward search from the fitted ``start`` model (module docstring).

    ``children(terms)``: the models one term larger that may follow ``terms``; ``fit(child, parent)``:
    the child fitted (from the parent's optimum), or a string saying why its fit failed;
    ``elpd(result)``: a fitted model's pointwise elpd; ``margin``: what a child must clear over its
    parent to become the current model; ``max_terms``: the largest model tried (None: no limit).
    """
    fitted, failed, path = {start: start_result}, [], [start]
    while True:
        current = path[-1]
        if max_terms is not None and len(current) >= max_terms:
            return SearchResult(fitted, failed, path, [])
        best, tried = None, []
        for child in children(current):
            if child in fitted:  # reached before by another path: its fit is reused
                result = fitted[child]
            else:
                result = fit(child, current)
                if isinstance(result, str):
                    failed.append({"terms": list(child), "message": result})
                    continue
                fitted[child] = result
            tried.append(child)
            if margin.beats(elpd(result), elpd(fitted[current]))[0] and (
                best is None or np.sum(elpd(result)) > np.sum(elpd(fitted[best]))
            ):
                best = child
        if best is None:
            return SearchResult(fitted, failed, path, tried)
        path.append(best)


def pseudo_bma_plus(elpd: np.ndarray, draws: int = BOOTSTRAP_DRAWS, seed: int = 0) -> np.ndarray:
    """Pseudo-BMA+ weights [-] of models from their pointwise elpd (models, units) (Yao et al. 2018)."""
    rng = np.random.default_rng(seed)
    n = elpd.shape[1]
    alpha = rng.dirichlet(np.ones(n), size=draws)  # (draws, units)
    z = n * alpha @ elpd.T  # (draws, models)
    z -= z.max(axis=1, keepdims=True)
    w = np.exp(z)
    return (w / w.sum(axis=1, keepdims=True)).mean(axis=0)
