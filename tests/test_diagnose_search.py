"""The search over combinations shared by the diagnosis and the rig, its margin, its averaging, and
the robust range's widening to the expansions the search did not take (no engine: toy scores)."""

from __future__ import annotations

import numpy as np
import pytest

from shelljax.diagnose._robust import expansion_widening, robust_range
from shelljax.diagnose.internal import ANY_GAIN, Margin, elpd_difference, forward_search, pseudo_bma_plus

N_TRIALS = 12
# per-trial elpd gain [nats] of each term over the start model: a alone gains 6 nats (0.5 a trial),
# b alone 1, and b on top of a another 6 (a pair that neither term alone shows); c never helps
GAIN = {"a": 0.5, "b": 1 / 12, "c": -0.02}


def _toy_elpd(terms: tuple[str, ...], gain: dict = GAIN) -> np.ndarray:
    """Toy pointwise elpd of a model: the start's plus its terms' gains, with a small spread per trial."""
    spread = np.linspace(-0.05, 0.05, N_TRIALS)
    total = sum(gain[t] for t in terms) + (0.5 if {"a", "b"} <= set(terms) else 0.0)
    return -1.0 + spread * (1 + len(terms)) + total


def _search(margin, max_terms=None, failing=(), gain=GAIN):
    calls = []

    def children(current):
        return [tuple(sorted(current + (t,))) for t in "abc" if t not in current]

    def fit(child, parent):
        calls.append((child, parent))
        return f"{'+'.join(child)} did not converge" if child in failing else _toy_elpd(child, gain)

    result = forward_search((), _toy_elpd(()), children, fit, lambda e: e, margin, max_terms)
    return result, calls


def test_the_search_ranks_singles_then_expands_the_winner_while_it_clears_the_margin():
    result, calls = _search(Margin(4.0, 2.0))
    # singles from the start, then pairs of the winner a (each from a), then the triple from the pair
    assert calls == [
        (("a",), ()),
        (("b",), ()),
        (("c",), ()),
        (("a", "b"), ("a",)),
        (("a", "c"), ("a",)),
        (("a", "b", "c"), ("a", "b")),
    ]
    # a wins by 6 nats; a+b beats a by 1 + 6 = 7 nats; c adds nothing, so the triple does not clear
    assert result.path == [(), ("a",), ("a", "b")] and result.chosen == ("a", "b")
    assert result.children == [("a", "b", "c")]
    assert set(result.fitted) == {(), ("a",), ("b",), ("c",), ("a", "b"), ("a", "c"), ("a", "b", "c")}


def test_the_margin_decides_how_far_the_search_goes():
    # a alone gains 0.2 nats, b alone 1: both below the 4-nat margin, so nothing is chosen ...
    weak = {**GAIN, "a": 0.2 / N_TRIALS}
    strict, _ = _search(Margin(4.0, 2.0), gain=weak)
    rig, _ = _search(ANY_GAIN, gain=weak)
    assert strict.chosen == () and strict.children == [("a",), ("b",), ("c",)]
    # ... while the rig's rule (any gain out of sample) takes b, then the pair a+b it reveals
    assert rig.chosen == ("a", "b")


def test_failed_fits_are_reported_and_the_size_limit_stops_the_search():
    result, _ = _search(Margin(4.0, 2.0), max_terms=2, failing=(("a", "c"),))
    assert result.failed == [{"terms": ["a", "c"], "message": "a+c did not converge"}]
    assert ("a", "c") not in result.fitted and result.chosen == ("a", "b")
    # the limit: the pair is not expanded, and it has no fitted children to offer
    assert ("a", "b", "c") not in result.fitted and result.children == []


def test_elpd_difference_and_margin():
    better, worse = np.array([1.0, 2.0, 3.0, 6.0]), np.zeros(4)
    delta, se = elpd_difference(better, worse)
    # Δ = Σ differences; SE = √n · sd (population, as loo_compare's)
    assert delta == 12.0 and se == pytest.approx(2.0 * np.std([1.0, 2.0, 3.0, 6.0]))
    assert Margin(4.0, 2.0).beats(better, worse)[0]
    assert not Margin(4.0, 4.0).beats(better, worse)[0]  # 12 nats < 4 SE = 15.0
    assert ANY_GAIN.beats(worse + 1e-9, worse)[0] and not ANY_GAIN.beats(worse, worse)[0]


def test_pseudo_bma_weights_favour_the_better_model_and_sum_to_one():
    elpd = np.stack([_toy_elpd(("a",)), _toy_elpd(()), _toy_elpd(("a",))])
    w = pseudo_bma_plus(elpd)
    # 6 nats apart: exp(-6) ≈ 0.25 % for the worse; two identical models share the rest equally
    assert w.sum() == pytest.approx(1.0) and w[1] < 0.01 and w[0] == pytest.approx(w[2])


def _estimate(e_value: float, rel: float = 0.05) -> dict:
    """A model's estimates: one session's P_g [Pa] and E [Pa], 95 % intervals ×/÷ e^(1.96 rel)."""
    k = np.exp(1.96 * rel)
    return {
        "gauge_pressure": [{"value": 1000.0, "ci95": [1000.0 / k, 1000.0 * k], "unit": "Pa"}],
        "young_modulus": {"value": e_value, "ci95": [e_value / k, e_value * k], "unit": "Pa"},
    }


def test_the_robust_range_covers_an_expansion_that_moves_e_beyond_the_chosen_interval():
    estimates = {"x": _estimate(2.0e6), "x+y": _estimate(2.4e6), "x+z": _estimate(2.02e6)}
    kept = [{"effect": "x"}]  # the expansions are excluded here: only the widening may let them in
    widening = expansion_widening(["x+z", "x+y"], estimates, "x", structure=[], decisive=True)
    # x+z is the best expansion (decisive verdict: covered, no warning); x+y moves E by +20 %,
    # beyond x's ±10 % interval: covered, with a warning that says so
    assert [w["effect"] for w in widening] == ["x+z", "x+y"]
    assert widening[0]["reason"] is None and "moves E by +20 %" in widening[1]["reason"]
    robust = robust_range(kept, estimates, "x", widening)
    e = robust["young_modulus"]
    assert e["range95"][1] == pytest.approx(estimates["x+y"]["young_modulus"]["ci95"][1])
    assert "adding y moves E" in robust["warning"] and robust["widened_by"] == widening
    # without the widening the range is the chosen model's own interval, and misses x+y's E
    alone = robust_range(kept, estimates, "x")["young_modulus"]["range95"]
    assert (
        alone[1] < estimates["x+y"]["young_modulus"]["value"] and robust_range(kept, estimates, "x")["warning"] is None
    )


def test_residual_structure_widens_the_range_to_every_expansion():
    estimates = {"baseline": _estimate(2.0e6), "y": _estimate(2.05e6), "z": _estimate(1.7e6)}
    widening = expansion_widening(["y", "z"], estimates, "baseline", structure=["observable:depth"], decisive=False)
    assert [w["effect"] for w in widening] == ["y", "z"]
    assert all("still misfits (observable:depth)" in w["reason"] for w in widening)
    warning = robust_range([{"effect": "baseline"}], estimates, "baseline", widening)["warning"]
    assert warning.count("still misfits") == 1 and warning.endswith("what it may lack, y, z")
    e = robust_range([{"effect": "baseline"}], estimates, "baseline", widening)["young_modulus"]
    assert e["range95"][0] == pytest.approx(estimates["z"]["young_modulus"]["ci95"][0])
    # no structure, no E beyond the interval, no decisive verdict: nothing to add
    assert expansion_widening(["y"], estimates, "baseline", structure=[], decisive=False) == []
