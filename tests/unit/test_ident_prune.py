"""Rule (viii) of the effect search (control/identification/effects.py ``prune``): an effect
accepted early is judged again against the final model without it, and dropped when a later
one has taken its share; an effect the final model still needs stays."""

from __future__ import annotations

import numpy as np

from control.identification.effect_rules import NoiseFloor, Options
from control.identification.effects import ALL_ALONG, Accepted, SearchState, prune
from control.identification.lsq import BlockLS, contiguous_folds
from control.identification.terms import EffectTerm

T = 4000
NOISE = 0.05


def _smooth(rng: np.random.Generator) -> np.ndarray:
    """A slowly varying signal (a random walk, smoothed, unit RMS)."""
    x = np.convolve(np.cumsum(rng.standard_normal(T)), np.ones(50) / 50, mode="same")
    x -= x.mean()
    return x / np.sqrt(np.mean(x**2))


def _search(seed: int, own: float) -> tuple[BlockLS, SearchState, list[EffectTerm]]:
    """One joint: y = base + (the true effect b) + ``own`` × another signal + noise. Term a's
    column is b plus 0.3 of that other signal, so a was accepted first (it explains most of
    b) and b after it; with ``own`` 0 the final model needs a no more, with ``own`` 1 it still
    needs a for the other signal."""
    rng = np.random.default_rng(seed)
    base, b, other = _smooth(rng), _smooth(rng), _smooth(rng)
    y = 3.0 * base + 2.0 * b + own * other + NOISE * rng.standard_normal(T)
    ls = BlockLS(y[:, None], contiguous_folds(T, 5))
    a_term = EffectTerm("position_ripple", (0,), {"cycles_per_rev": 7})
    # (two columns without a sign rule: with own 1, b's coefficient comes out negative, which
    # rule (vii) refuses for a spring's stiffness)
    b_term = EffectTerm("position_ripple", (0,), {"cycles_per_rev": 11})
    ls.add("base", {0: base[:, None]})
    ls.add(a_term.key, {0: np.column_stack([b + 0.3 * other, np.zeros(T)])})
    ls.add(b_term.key, {0: np.column_stack([b, np.ones(T)])})
    zero = np.zeros(1)
    state = SearchState(
        names=["base", a_term.key, b_term.key],
        effects=[a_term, b_term],
        accepted=[
            Accepted(a_term, zero, ALL_ALONG, (0,), zero, zero),
            Accepted(b_term, zero, ALL_ALONG, (0,), zero, zero),
        ],
    )
    return ls, state, [a_term, b_term]


def _prune_all(ls: BlockLS, state: SearchState):
    weights = np.ones(1)
    noise = NoiseFloor(np.full(1, NOISE), np.full(1, NOISE**2))
    said: list[str] = []
    current = ls.evaluate(state.names, weights)
    after, dropped = prune(ls, state, current, weights, noise, Options(), None, None, said.append)
    return after, dropped, said


def test_an_effect_a_later_one_made_redundant_is_dropped_and_the_needed_one_stays():
    for seed in range(5):
        ls, state, (_, b_term) = _search(seed, own=0.0)
        after, dropped, said = _prune_all(ls, state)
        assert [acc.term for acc in state.accepted] == [b_term], said
        assert state.names == ["base", b_term.key]
        assert [r["name"] for r in dropped] == ["position_ripple"]
        assert "rule viii" in dropped[0]["reason"]
        assert any("dropped on the final fit position_ripple" in s for s in said), said
        # what stays is evaluated without the dropped term
        assert np.allclose(after.cv_sse, ls.evaluate(["base", b_term.key], np.ones(1)).cv_sse)


def test_two_effects_the_final_model_needs_both_stay():
    for seed in range(5):
        ls, state, terms = _search(seed, own=1.0)
        _, dropped, said = _prune_all(ls, state)
        assert [acc.term for acc in state.accepted] == terms, said
        assert dropped == [] and said == []
