"""mogo.sampling against its written spec (the module docstring), on hand-made logits whose
answers are worked out here by hand: the tie rule, temperature, top-k, top-p, the inverse CDF,
the guidance formula and the -inf padding of the narrower levels. No torch: the torch reference
shares this sampler, so only known answers can tell whether it is right."""

import dataclasses
import math

import numpy as np
import pytest

from mogo import MotionGenerator, Sampling
from mogo.sampling import SamplingError, choose_token, choose_tokens, make_rng, step_uniforms

GREEDY = Sampling(temperature=0)


def guided(scale: float, temperature=1.0, top_k=0, top_p=1.0) -> Sampling:
    return Sampling(temperature=temperature, top_k=top_k, top_p=top_p, guidance=scale)


# -- ties and the inverse CDF -----------------------------------------------------------------
def test_greedy_takes_the_first_of_tied_maxima():
    assert choose_token(np.array([1.0, 3.0, 3.0, 0.0]), None, 0.99, GREEDY) == 1
    assert choose_token(np.zeros(600), None, 0.99, GREEDY) == 0


@pytest.mark.parametrize("uniform,token", [(0.2, 1), (0.6, 2), (0.95, 0), (0.99, 3)])
def test_ties_are_sorted_lower_id_first(uniform, token):
    """[1, 3, 3, 0] sorted: ids 1, 2, 0, 3 with weights 1, 1, e^-2, e^-3 (total 2.185): the
    boundaries of the inverse CDF lie at 0.458, 0.915 and 0.977."""
    assert choose_token(np.array([1.0, 3.0, 3.0, 0.0]), None, uniform, Sampling()) == token


@pytest.mark.parametrize("uniform", [0.0, 0.0004, 0.1234, 0.5, 0.77777, 0.9999])
def test_many_ties_keep_id_order_and_the_cdf_is_inverted_exactly(uniform):
    """600 equal logits (wider than the 16 an insertion sort is stable for): the stable sort
    keeps ids in order, the cumulative weights are 1, 2, ..., 600, so uniform u picks
    floor(600 u)."""
    assert choose_token(np.zeros(600), None, uniform, Sampling()) == math.floor(600 * uniform)


def test_ties_among_many_values_keep_id_order_within_each_value():
    """600 logits of three values: sorted by value, ids ascending within a value; the draw for
    u is the entry where the cumulative weight first exceeds u times the total, computed here
    in plain Python."""
    values = np.random.default_rng(3).integers(0, 3, 600).astype(np.float64)
    order = sorted(range(600), key=lambda i: (-values[i], i))
    weights = [math.exp(values[i] - 2) for i in order]
    total, cumulative = sum(weights), np.cumsum(weights)
    for u in np.linspace(0.0005, 0.9995, 200):
        expected = order[int(np.searchsorted(cumulative, u * total, side="right"))]
        assert choose_token(values, None, u, Sampling()) == expected


def _by_the_spec(values: list[float], u: float, top_k: int, top_p: float) -> int:
    """The module docstring's rule in plain Python (temperature 1, no guidance)."""
    order = sorted(
        (i for i in range(len(values)) if math.isfinite(values[i])), key=lambda i: (-values[i], i)
    )[: top_k or None]
    weights = [math.exp(values[i] - values[order[0]]) for i in order]
    cumulative = np.cumsum(weights)
    kept = [k for k in range(len(order)) if cumulative[k] - weights[k] < top_p * cumulative[-1]]
    total = cumulative[len(kept) - 1]
    return order[next(k for k in kept if cumulative[k] > u * total)]


@pytest.mark.parametrize("top_k,top_p", [(0, 1.0), (5, 1.0), (0, 0.6), (40, 0.9)])
def test_a_batch_of_tied_untied_and_padded_rows_draws_as_the_spec_row_by_row(top_k, top_p):
    """Rows with ties (few values: top-k then cuts inside a tie), rows without, and rows
    padded with -inf, in one call: each row as the rule says, whatever its neighbours."""
    rng = np.random.default_rng(11)
    rows = [
        rng.integers(0, 4, 64).astype(np.float64),  # ties everywhere
        rng.normal(size=64),  # none
        np.concatenate([rng.integers(0, 3, 20).astype(np.float64), np.full(44, -np.inf)]),
        np.concatenate([rng.normal(size=30), np.full(34, -np.inf)]),
        np.where(np.arange(64) % 7 == 0, 2.0, rng.normal(size=64)),
    ]  # one tied value
    for u in np.linspace(0.001, 0.999, 25):
        drawn = choose_tokens(
            np.array(rows), None, np.full(len(rows), u), Sampling(top_k=top_k, top_p=top_p)
        )
        assert drawn.tolist() == [_by_the_spec(list(r), u, top_k, top_p) for r in rows]


def test_the_first_entry_whose_cumulative_weight_exceeds_u_times_the_total_is_taken():
    """Four equal weights: c = 1, 2, 3, 4 and u * total = 1.0 exactly for u = 0.25. The rule is
    c > u * total (strict), so id 1 and not id 0."""
    assert choose_token(np.zeros(4), None, 0.25, Sampling()) == 1
    assert choose_token(np.zeros(4), None, 0.2499, Sampling()) == 0


# -- temperature -------------------------------------------------------------------------------
def test_temperature_zero_is_argmax_whatever_the_uniform_and_filters():
    logits = np.random.default_rng(0).normal(size=(20, 513))
    for row in logits:
        for uniform in (0.0, 0.5, 0.999):
            for sampling in (GREEDY, Sampling(temperature=0, top_k=3, top_p=0.2)):
                assert choose_token(row, None, uniform, sampling) == np.argmax(row)


@pytest.mark.parametrize(
    "temperature,boundary", [(1.0, 0.75), (2.0, math.sqrt(3) / (1 + math.sqrt(3))), (0.5, 0.9)]
)
def test_temperature_divides_the_logits(temperature, boundary):
    """Logits [0, ln 3]: weights 1 : 3 ** (1 / T), so id 1 is drawn below u = w1 / (w0 + w1)
    and id 0 above it."""
    logits = np.array([0.0, math.log(3)])
    sampling = Sampling(temperature=temperature)
    assert choose_token(logits, None, boundary - 1e-6, sampling) == 1
    assert choose_token(logits, None, boundary + 1e-6, sampling) == 0


# -- top-k and top-p ---------------------------------------------------------------------------
def test_top_k_keeps_the_k_largest():
    """[0, 2, 1, 3]: k=2 keeps ids 3 and 1 (weights 1, e^-1; boundary 0.731)."""
    logits = np.array([0.0, 2.0, 1.0, 3.0])
    assert choose_token(logits, None, 0.99, Sampling(top_k=2)) == 1
    assert choose_token(logits, None, 0.72, Sampling(top_k=2)) == 3
    assert choose_token(logits, None, 0.74, Sampling(top_k=2)) == 1
    assert choose_token(logits, None, 0.99, Sampling(top_k=1)) == 3
    assert choose_token(logits, None, 0.99, Sampling()) == 0  # off: the whole CDF
    assert choose_token(logits, None, 0.99, Sampling(top_k=10)) == 0  # more than there are
    assert all(
        choose_token(logits, None, u, Sampling(top_k=2)) in (1, 3)
        for u in np.linspace(0, 0.9999, 101)
    )


PROBS = np.log([0.5, 0.3, 0.15, 0.05])  # mass before each entry: 0, 0.5, 0.8, 0.95
LARGEST_UNIFORM = np.nextafter(1.0, 0.0)  # the largest value rng.random() returns


@pytest.mark.parametrize(
    "logits,sampling,last_kept",
    [
        (PROBS, Sampling(), 3),
        (PROBS, Sampling(top_k=2), 1),
        (PROBS, Sampling(top_p=0.9), 2),
        (PROBS, Sampling(top_k=3, top_p=0.82), 1),
        (np.array([0.0, 1.0, -np.inf, -np.inf]), Sampling(), 0),
    ],
)
def test_the_largest_uniform_draws_the_last_kept_entry(logits, sampling, last_kept):
    """u = 1 - 2**-53 still lands inside the kept mass (u * total < total in float64): the last
    kept entry, never one past the top-k or top-p cut, never a padding column."""
    assert choose_token(logits, None, LARGEST_UNIFORM, sampling) == last_kept


@pytest.mark.parametrize(
    "top_p,last_kept", [(1.0, 3), (0.96, 3), (0.9, 2), (0.79, 1), (0.51, 1), (0.49, 0), (1e-9, 0)]
)
def test_top_p_keeps_entries_whose_preceding_mass_is_below_top_p(top_p, last_kept):
    """An entry stays while the mass before it is < top_p; at u -> 1 the last kept one is
    drawn, at u -> 0 the first. At least one entry always stays."""
    sampling = Sampling(top_p=top_p)
    assert choose_token(PROBS, None, 0.9999, sampling) == last_kept
    assert choose_token(PROBS, None, 0.0, sampling) == 0


def test_top_p_drops_an_entry_whose_preceding_mass_equals_top_p():
    """Four equal weights, top_p=0.5: the masses before the entries are 0, 1/4, 1/2, 3/4 (all
    exact); 1/2 is not < 0.5, so ids 0 and 1 stay, and u -> 1 draws id 1."""
    assert choose_token(np.zeros(4), None, 0.9999, Sampling(top_p=0.5)) == 1
    assert choose_token(np.zeros(4), None, 0.9999, Sampling(top_p=0.5001)) == 2


def test_top_p_is_measured_on_what_top_k_kept():
    """top_k=3 keeps mass 0.95; top_p=0.82 of that is 0.779 < 0.8, so only ids 0 and 1 stay
    (measured on the full mass, 0.82 > 0.8 would keep id 2 too)."""
    sampling = Sampling(top_k=3, top_p=0.82)
    assert choose_token(PROBS, None, 0.9999, sampling) == 1
    # inside the kept set the CDF is renormalised: id 1 from u > 0.5 / 0.8
    assert choose_token(PROBS, None, 0.62, sampling) == 0
    assert choose_token(PROBS, None, 0.63, sampling) == 1


def test_padding_columns_are_never_drawn_nor_counted_by_top_k():
    logits = np.array([0.0, 1.0, -np.inf, -np.inf])
    for u in np.linspace(0, 0.9999, 50):
        assert choose_token(logits, None, u, Sampling(top_k=3)) in (0, 1)
        assert choose_token(logits, None, u, Sampling()) in (0, 1)


# -- the forbidden token -----------------------------------------------------------------------
def test_a_forbidden_token_is_never_drawn():
    logits = np.array([0.0, 1.0, 9.0])
    assert choose_token(logits, None, 0.5, GREEDY, forbid=2) == 1
    assert all(
        choose_token(logits, None, u, Sampling(), forbid=2) != 2 for u in np.linspace(0, 0.9999, 50)
    )
    assert choose_token(logits, None, 0.5, GREEDY) == 2


# -- guidance ----------------------------------------------------------------------------------
COND, UNCOND = np.array([0.0, 3.0, 0.0]), np.array([0.0, 0.0, 3.0])


@pytest.mark.parametrize(
    "scale,token", [(1.0, 1), (2.0, 1), (0.5, 1), (0.0, 2), (-1.0, 2), (0.25, 2)]
)
def test_guidance_is_uncond_plus_scale_times_the_difference(scale, token):
    """Effective logits u + s (c - u) = [0, 3s, 3 - 3s]: id 1 from s = 0.5 on (a tie at 0.5,
    the lower id), id 2 below. s = 1 is the conditional logits alone; s < 1 is applied as
    written (s = 0: the unconditional logits), not refused and not ignored."""
    sampling = guided(scale, temperature=0)
    assert sampling.guided == (scale != 1)
    assert choose_token(COND, UNCOND, 0.5, sampling) == token


def test_guided_sampling_draws_from_the_effective_logits():
    rng = np.random.default_rng(1)
    cond, uncond = rng.normal(size=(2, 8, 64)) * 2
    for scale in (0.5, 2.0, 3.5):
        effective = uncond + scale * (cond - uncond)
        for sampling in (guided(scale), guided(scale, top_p=0.7)):
            plain = Sampling(sampling.temperature, sampling.top_k, sampling.top_p)
            for u in np.linspace(0.01, 0.99, 25):
                uniforms = np.full(8, u)
                assert np.array_equal(
                    choose_tokens(cond, uncond, uniforms, sampling),
                    choose_tokens(effective, None, uniforms, plain),
                )


def test_scale_one_ignores_the_unconditional_logits_and_other_scales_need_them():
    assert choose_token(COND, UNCOND, 0.5, GREEDY) == choose_token(COND, None, 0.5, GREEDY) == 1
    with pytest.raises(ValueError, match="needs unconditional logits"):
        choose_token(COND, None, 0.5, guided(2.0))


@pytest.mark.parametrize(
    "sampling", [guided(2.0, temperature=0), guided(2.0), guided(0.5, top_k=5)]
)
def test_guidance_never_picks_a_padding_column(sampling):
    """A finer level has one class less than level 0 (no end token): its row is padded with
    -inf in both branches, where u + s (c - u) would be NaN, which argmax would pick."""
    cond = np.array([[-5.0, -6.0, -np.inf], [1.0, 0.5, 2.0]])
    uncond = np.array([[-7.0, -3.0, -np.inf], [0.0, 0.0, 2.5]])
    for u in (0.0, 0.5, 0.9999):
        tokens = choose_tokens(cond, uncond, np.array([u, u]), sampling)
        assert tokens[0] in (0, 1)
    if sampling.temperature == 0:
        assert choose_tokens(cond, uncond, np.zeros(2), sampling)[0] == 0  # [-3, -9, -inf]


def test_guidance_keeps_the_forbidden_token_out():
    cond, uncond = np.array([0.0, 1.0, 5.0]), np.array([0.0, 1.0, 1.0])
    assert choose_token(cond, uncond, 0.5, guided(2.0, temperature=0), forbid=2) == 1


# -- rows and seeds ----------------------------------------------------------------------------
def test_rows_are_drawn_independently_each_with_its_own_uniform():
    rng = np.random.default_rng(2)
    logits = rng.normal(size=(6, 513)) * 3
    logits[1:, 512] = -np.inf  # levels above 0: one class less
    uniforms = rng.random(6)
    forbid = [512, None, None, None, None, None]
    for sampling in (Sampling(), Sampling(top_k=20, top_p=0.8, temperature=0.7)):
        together = choose_tokens(logits, None, uniforms, sampling, forbid)
        alone = [choose_token(logits[r], None, uniforms[r], sampling, forbid[r]) for r in range(6)]
        assert together.tolist() == alone


def test_the_seed_maps_to_pcg64_uniforms_one_per_level_per_step():
    rng = make_rng(1234)
    drawn = np.array([step_uniforms(rng, 6) for _ in range(3)])
    expected = np.random.Generator(np.random.PCG64(1234)).random(18).reshape(3, 6)
    assert np.array_equal(drawn, expected)


@pytest.mark.parametrize(
    "options,message",
    [
        (dict(temperature=-0.1), "temperature must be >= 0"),
        (dict(temperature=float("nan")), "temperature must be finite, got nan"),
        (dict(temperature=float("inf")), "temperature must be finite, got inf"),
        (dict(temperature=1e-320), r"temperature must be 0 \(greedy\) or at least 1e-06"),
        (dict(temperature=10**400), "temperature must be finite"),
        (dict(top_k=-1), "top_k must be >= 0"),
        (dict(top_p=0.0), r"top_p must be in \(0, 1\]"),
        (dict(top_p=-0.5), r"top_p must be in \(0, 1\]"),
        (dict(top_p=1.5), r"top_p must be in \(0, 1\]"),
        (dict(top_p=float("nan")), "top_p must be finite, got nan"),
        (dict(guidance=float("nan")), "guidance must be finite, got nan"),
        (dict(guidance=float("-inf")), "guidance must be finite, got -inf"),
        (dict(guidance=1e300), "guidance must be between -1000000 and 1000000"),
    ],
)
def test_bad_options_are_refused(options, message):
    with pytest.raises(SamplingError, match=message) as refused:
        Sampling(**options)
    assert refused.value.option == next(iter(options))  # for the command's flag name


@pytest.mark.parametrize(
    "options,message",
    [
        (dict(temperature="0.5"), "temperature must be a number, got str"),
        (dict(top_k=2.0), "top_k must be an integer, got float"),
        (dict(guidance=True), "guidance must be a number, got bool"),
        (dict(top_p=None), "top_p must be a number, got NoneType"),
    ],
)
def test_options_of_the_wrong_type_are_refused(options, message):
    """No text converted behind the caller's back, no bool taken for a number."""
    with pytest.raises(TypeError, match=message):
        Sampling(**options)


def test_a_checked_sampling_cannot_be_changed_behind_its_checks():
    """Frozen: no field can be set to a value the checks refuse; equal options hash equal."""
    sampling = Sampling(top_p=0.9)
    with pytest.raises(dataclasses.FrozenInstanceError):
        sampling.top_p = -1.0
    assert {sampling: "kept"}[Sampling(top_p=0.9)] == "kept"


def test_updated_replaces_the_options_given_and_refuses_unknown_names():
    """None is "not given". An unknown name is refused naming the first in sorted order (the
    same message whatever order the caller gave) and listing the options."""
    assert Sampling(top_k=4).updated(dict(top_p=0.5, temperature=None)) == Sampling(1.0, 4, 0.5)
    listed = "; the options are temperature, top_k, top_p, guidance$"
    for options in (dict(warmth=1, beam=2), dict(beam=2, warmth=1)):
        with pytest.raises(TypeError, match="unknown sampling option 'beam'" + listed):
            Sampling().updated(options)
    with pytest.raises(TypeError, match="unknown sampling option 'warmth'" + listed):
        Sampling().updated(dict(top_k=2, warmth=1))


def test_numpy_numbers_are_stored_as_the_fields_own_types():
    sampling = Sampling(np.float32(0.5), np.int64(7), np.float64(0.9), 2)
    assert sampling == Sampling(0.5, 7, 0.9, 2.0)
    assert [type(getattr(sampling, f)) for f in ("temperature", "top_k", "top_p", "guidance")] == [
        float,
        int,
        float,
        float,
    ]


def test_top_k_beyond_the_number_of_classes_keeps_them_all():
    """k above the row's width is top-k off, however large (2**70 overflowed numpy)."""
    logits = np.random.default_rng(4).normal(size=(3, 513))
    for u in (0.1, 0.5, 0.9):
        uniforms = np.full(3, u)
        assert np.array_equal(
            choose_tokens(logits, None, uniforms, Sampling(top_k=2**70)),
            choose_tokens(logits, None, uniforms, Sampling()),
        )


@pytest.mark.parametrize(
    "sampling",
    [
        Sampling(temperature=1e-6),
        guided(-1e6),
        guided(1e6),
        guided(1e6, temperature=1e-6, top_p=0.5),
    ],
)
def test_the_extremes_allowed_still_give_real_tokens(sampling):
    """At the bounds the float64 arithmetic stays finite for float32 logits of any size: the
    token is a real class, never a -inf padding column."""
    big = np.finfo(np.float32).max
    cond = np.array([[big, -big, 0.0, -np.inf], [1.0, 2.0, -3.0, -np.inf]])
    uncond = np.array([[-big, big, 1.0, -np.inf], [0.5, -2.0, 3.0, -np.inf]])
    for u in (0.0, 0.5, 0.9999):
        tokens = choose_tokens(cond, uncond, np.full(2, u), sampling)
        assert all(0 <= t < 3 for t in tokens)


@pytest.fixture(scope="module")
def generator():
    return MotionGenerator.load()


def test_a_batch_of_prompts_draws_each_with_its_own_seed(generator):
    """A batch [a, b] with seed s is generate(a, seed=s) and generate(b, seed=s + 1), as
    Motion.seed says."""
    prompts = ["a person walks forward.", "someone waves."]
    batch = generator.generate_batch(prompts, seconds=1.5, seed=5)
    alone = [generator.generate(p, seconds=1.5, seed=5 + k) for k, p in enumerate(prompts)]
    assert [m.seed for m in batch] == [5, 6]
    for together, single in zip(batch, alone, strict=False):
        assert np.array_equal(together.tokens, single.tokens)
        assert np.array_equal(together.joints, single.joints)
    same_seed = generator.generate(prompts[1], seconds=1.5, seed=5)
    assert not np.array_equal(same_seed.tokens, batch[1].tokens)
