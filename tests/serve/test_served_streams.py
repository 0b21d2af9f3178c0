"""Served streams on the engine's clock: the tokens of `mogo stream` for the same prompt, seed
and switches, whatever else runs; a switch changes what a stream does, a burst of new streams
all start, streams at any step of their clips share one call of each level graph."""

import numpy as np
import pytest

pytest.importorskip("onnx")

from helpers import counted_prefills
from mogo import Anchoring, kv_pool
from mogo import generator as generator_module
from mogo.serve import engine as engine_module
from mogo.serve.engine import Engine
from mogo.token_generator import TokenGenerator, TokenStream, step_together


def served(engine, prompts: dict[int, str], seed: int, steps: int) -> np.ndarray:
    """One stream's joints over `steps` token steps, the prompt switched at the steps given."""
    stream = engine.open(prompts[0], seed, engine.generator.sampling(None), 0.0)
    frames = []
    while stream.steps < steps:
        if stream.steps in prompts:
            engine.switch(stream, prompts[stream.steps])
        frames += [joints for _, _, joints in engine.round([stream])]
    engine.close(stream)
    assert not len(engine.tokens.pool)  # its cache's row freed
    return np.concatenate(frames)


def test_a_served_switch_changes_the_frames_after_it(generator, engine_parts):
    engine = Engine(generator, 1, tokens=engine_parts)
    walk = {0: "a person walks forward."}
    plain = served(engine, walk, 5, 120)
    switched = served(engine, walk | {60: "a person jumps on the spot."}, 5, 120)
    lookahead = generator.manifest.vq.decoder.lookahead
    before = 60 - lookahead - 8  # frames no token after the switch reaches (feet: 8 more)
    n = min(len(plain), len(switched))
    assert n > 70
    np.testing.assert_allclose(switched[:before], plain[:before], atol=1e-5)
    assert np.abs(switched[60:n] - plain[60:n]).max() > 0.1


def test_a_burst_of_new_streams_all_start(generator, engine_parts):
    """More new streams than a round's solo steps: each still reaches its first frame."""
    engine = Engine(generator, 1, tokens=engine_parts)
    sampling = generator.sampling(None)
    burst = [engine.open("a person walks forward.", k, sampling, 0.0) for k in range(25)]
    started, now = set(), 0.0
    while len(started) < len(burst) and now < 8.0:
        due = engine.due(now)
        started |= {stream.id for stream, _, _ in engine.round(due)} if due else set()
        now = round(now + (0 if due else 0.05), 6)
    assert started == {stream.id for stream in burst}


def test_a_burst_beside_running_streams_takes_what_they_leave_of_a_round(generator, engine_parts):
    """With streams running, a round steps every running one due and only as many new ones as
    fit beside them in about a tick (at the rounds' measured cost a step), the oldest first,
    never fewer than MIN_CATCH_UP; on an idle server every new one."""
    engine = Engine(generator, 1, tokens=engine_parts)
    sampling = generator.sampling(None)
    running = [engine.open("a person walks forward.", k, sampling, 0.0) for k in range(6)]
    now = 0.0
    while not all(s.frames_emitted for s in running) or engine.due(now):
        due = engine.due(now)
        engine.round(due) if due else None
        now = round(now + (0 if due else 0.05), 6)
    burst = [engine.open("a person waves.", 10 + k, sampling, now) for k in range(20)]
    tick = 1 / engine.fps
    engine._step_seconds = tick / 16  # a round of a tick holds 16 steps: 6 running, 10 new
    due = engine.due(now + tick)
    assert due[:6] == running and due[6:] == burst[:10]
    engine._step_seconds = tick / 5  # the running ones fill it: the new ones' least
    assert engine.due(now + tick)[6:] == burst[: engine_module.MIN_CATCH_UP]
    assert engine.due(now) == burst[:5]  # a round between ticks, none running due: 5 new
    for stream in running:  # the running ones gone: the burst steps whole
        engine.close(stream)
    assert engine.due(now + tick) == burst


STREAMS = [
    ("a person walks forward.", 3, {}),
    ("a person jogs forward.", 4, {"guidance": 2.0}),
    ("a person waves.", 5, {"top_k": 40}),
    ("a person walks forward.", 6, {}),
]
SWITCHES = {0: (100, "a person jumps on the spot."), 1: (150, "a person turns left.")}
STEPS = 128 + 2 * 8 + 30  # past the shipped window and two of the old stepper's compactions


def drawn_served(generator, engine_parts, threads: int) -> list[np.ndarray]:
    """Each stream's token rows, all stepped together by one engine (on two threads: every
    call's levels in two groups at once), a later stream and switches included."""
    engine = Engine(generator, threads, tokens=engine_parts)
    assert len(engine.tokens.level_groups) == threads
    streams = [
        engine.open(prompt, seed, generator.sampling(None, **options), 0.0)
        for prompt, seed, options in STREAMS
    ]
    late = engine.open("a person jumps.", 9, generator.sampling(None), 0.0)
    rows: list[list[np.ndarray]] = [[] for _ in streams]
    while min(s.steps for s in streams) < STEPS:
        for k, stream in enumerate(streams):
            if k in SWITCHES and stream.steps == SWITCHES[k][0]:
                engine.switch(stream, SWITCHES[k][1])
        due = [s for s in streams if s.steps < STEPS] + ([late] if streams[0].steps > 20 else [])
        engine.round(due)
        for k, stream in enumerate(streams):
            if stream in due:  # the step's row, also where it started a clip or re-anchored
                rows[k].append(stream.tokens.last.copy())
    engine.shutdown()
    return [np.array(r) for r in rows]


@pytest.mark.parametrize("threads", [1, 2], ids=["one-thread", "two-threads"])
def test_served_streams_draw_the_tokens_of_mogo_stream(generator, engine_parts, threads):
    """The shipped bundle's window (128) is beyond its relative distances (64); re-anchored,
    fresh clips and holds included: the same rows as a MotionStream of the same prompt, seed,
    sampling and switches (guided streams step alone on the bundle's own graphs)."""
    served = drawn_served(generator, engine_parts, threads)
    anchors = 0
    for k, (prompt, seed, options) in enumerate(STREAMS):
        stream = generator.stream(prompt, seed=seed, **options)
        expected = []
        for n in range(STEPS):
            if k in SWITCHES and n == SWITCHES[k][0]:
                stream.set_prompt(SWITCHES[k][1])
            stream.step()
            expected.append(stream.tokens.last.copy())
        anchors += stream.anchor.anchors
        assert np.array_equal(served[k], np.array(expected)), f"stream {k}"
    assert anchors >= 2 * len(STREAMS)


def test_step_together_gives_each_stream_its_own_tokens_in_any_group(generator, engine_parts):
    """Streams stepped in changing company draw what each draws stepped alone: a group of
    other members after a shared call, the same group again (its presents reused), and again
    after one member's cache was recomputed under a new prompt."""
    sampling = generator.sampling(None)
    walk, wave = generator.embed(["a person walks forward.", "a person waves."])

    def run(together: bool) -> list[list[np.ndarray]]:
        a, b, c = (
            engine_parts.start(walk, seed, sampling, 128, allow_end=False) for seed in range(3)
        )
        schedule = [[a, b], [c], [a, c], [b], [a, b], [a, b], "switch", [a, b], [a, b], [c]]
        drawn = {id(s): [] for s in (a, b, c)}
        for group in schedule:
            if group == "switch":
                b.set_prompt(wave)  # same layout, its cache recomputed
                continue
            rows = step_together(group) if together else [s.step() for s in group]
            for stream, row in zip(group, rows, strict=False):
                drawn[id(stream)].append(row)
        return [np.array(rows) for rows in drawn.values()]

    for alone, together in zip(run(False), run(True), strict=False):
        assert np.array_equal(alone, together)


def test_a_served_stream_gives_mogo_streams_frames_feet_planted_or_not(generator, engine_parts):
    """Past a re-anchor: the same decoding, joints and foot planting (mogo.motion.feet)."""
    for plant_feet in (True, False):
        engine = Engine(generator, 1, tokens=engine_parts)
        stream = engine.open("a person walks forward", 3, generator.sampling(None), 0.0, plant_feet)
        got = []
        while sum(map(len, got)) < 120:
            got += [joints for _, _, joints in engine.round([stream])]
        assert stream.anchor.anchors >= 1
        served = np.concatenate(got)
        local = generator.stream("a person walks forward", seed=3, plant_feet=plant_feet)
        expected = np.array(list(local.frames(limit=len(served))))
        np.testing.assert_allclose(served, expected, atol=1e-5)


def test_streams_at_any_step_share_one_call_of_each_level_graph(
    generator, engine_parts, monkeypatch
):
    """Each round draws its rows with one call of each level graph per pool bucket
    (mogo.kv_pool) its streams are in, whatever steps of their clips they are at. Four
    streams start together; one 0.3 s later catches up in calls of its own, then steps in
    theirs at another step of its clip."""
    calls: list[tuple[int, tuple]] = []
    run = TokenGenerator.run

    def counted(self, level, prompt, uncond, token_ids, positions, *args):
        # a step: pooled, or a lone row on the graphs as exported (a pooled stream's prefill
        # has one vector of positions too, on the pooled graphs)
        if positions.ndim == 2 or self.pool is None:
            calls.append((level, tuple(positions.reshape(len(prompt), -1)[:, 0])))
        return run(self, level, prompt, uncond, token_ids, positions, *args)

    def drawn_counted(streams):
        calls.clear()
        steps = [s.steps for s in streams]
        drawn = step_together(streams)
        buckets = {s.generator.pool.place[id(s)][0].capacity for s in streams}
        rounds.append((steps, buckets, list(calls)))
        return drawn

    monkeypatch.setattr(TokenGenerator, "run", counted)
    monkeypatch.setattr(generator_module, "step_together", drawn_counted)
    engine = Engine(generator, 1, tokens=engine_parts)
    sampling = generator.sampling(None)
    streams = [engine.open("a person walks forward.", k, sampling, 0.0) for k in range(4)]
    now, rounds = 0.0, []
    while now < 3.0:
        if now == 0.3 and len(streams) == 4:
            streams.append(engine.open("a person waves.", 9, sampling, now))
        due = engine.due(now)
        if due:
            engine.round(due)
        now = round(now + (0 if due else 0.05), 6)
    levels = generator.tokens.num_levels
    for steps, buckets, made in rounds:
        for level in range(levels):
            at = [a for lv, a in made if lv == level]
            assert len(at) <= len(buckets)  # one call per bucket (fresh clips' first steps
            assert sorted(sum(at, ())) == sorted(steps)  # come in a second shared call)
    together = [at for _, _, made in rounds for _, at in made if len(at) == 5]
    assert any(len(set(at)) > 1 for at in together)  # five streams at other steps, one call


def test_clips_ending_in_one_round_start_again_in_one_call(generator, engine_parts, monkeypatch):
    """Streams whose clips end in the same round draw their fresh clips' first steps in one
    shared call of each level graph, not one call each."""
    ends = TokenStream._ends
    monkeypatch.setattr(  # every clip ends at its step 6 (the model's end token, forced)
        TokenStream, "_ends", lambda self, row: None if self.steps == 6 else ends(self, row)
    )
    engine = Engine(generator, 1, tokens=engine_parts)
    sampling = generator.sampling(None)
    streams = [engine.open("a person walks forward.", k, sampling, 0.0) for k in range(3)]
    for _ in range(6):
        engine.round(streams)
    calls: list[tuple[int, tuple]] = []
    run = TokenGenerator.run

    def counted(self, level, prompt, uncond, token_ids, positions, *args):
        calls.append((level, tuple(positions[:, 0])))
        return run(self, level, prompt, uncond, token_ids, positions, *args)

    monkeypatch.setattr(TokenGenerator, "run", counted)
    engine.round(streams)
    assert [s.tokens.steps for s in streams] == [1, 1, 1]  # fresh clips, a step each
    assert all(s.anchor.fresh == 1 for s in streams)
    for level in range(generator.tokens.num_levels):  # the round's rows, then the 3 firsts
        assert [at for lv, at in calls if lv == level] == [(6, 6, 6), (0, 0, 0)]


def test_streams_re_anchored_in_one_round_prefill_in_one_call(generator, engine_parts, monkeypatch):
    """Streams that reach their anchoring span in the same round make their fresh clips'
    caches in one shared prefill, not one each (what they draw then: the test above)."""
    anchoring = Anchoring()
    engine = Engine(generator, 1, tokens=engine_parts)
    sampling = generator.sampling(None)
    streams = [engine.open("a person walks forward.", k, sampling, 0.0) for k in range(3)]
    for stream in streams:
        stream.tokens.allow_end = False  # no clip ends first
    for _ in range(anchoring.span - 1):
        engine.round(streams)
    prefills = counted_prefills(monkeypatch)
    engine.round(streams)
    assert [s.tokens.steps for s in streams] == [anchoring.keep] * 3  # each re-anchored
    assert [len(group) for group in prefills] == [3]


@pytest.mark.parametrize("window", [8, None], ids=["ring-window", "no-window"])
def test_a_pooled_stream_draws_what_it_draws_on_its_own_cache(generator, engine_parts, window):
    """The pool (mogo.kv_pool) against the bundle's own graphs: a full window's ring of slots,
    rows moving to larger buckets and back after a restart, a re-prefill at a switch, other
    streams in the same calls at other steps."""
    sampling = generator.sampling(None)
    walk, wave = generator.embed(["a person walks forward.", "a person waves."])
    tokens = engine_parts.with_own_pool()
    pooled = tokens.start(walk, 7, sampling, window, allow_end=False)
    others = [tokens.start(wave, seed, sampling, None, allow_end=False) for seed in range(2)]
    own = generator.tokens.start(walk, 7, sampling, window, allow_end=False)
    for n in range(75):
        if n == 30:
            pooled.set_prompt(wave)
            own.set_prompt(wave)
        if n == 50:
            pooled.restart()
            own.restart()
        rows = step_together([pooled, *others[: n % 3]])
        assert np.array_equal(rows[0], own.step()), f"step {n}"
    assert len(tokens.pool.buckets) >= 2  # rows moved to a larger bucket


def test_a_lone_row_steps_on_the_graphs_as_exported(generator, engine_parts, monkeypatch):
    """A call of one pooled row runs the bundle's graphs as exported, as a stream's own cache
    does (cheaper than the row-wise stages at one row): the same tokens, and the same slots in
    its row of the pool as in the own cache, bit for bit, past a full window."""
    tokens = engine_parts.with_own_pool()
    on_exported: list[bool] = []
    run = TokenGenerator.run

    def counted(self, level, *args):
        if self is not generator.tokens:  # the pooled stream's calls, not the own one's
            on_exported.append(self is tokens.alone)
        return run(self, level, *args)

    (walk,) = generator.embed(["a person walks forward."])
    sampling = generator.sampling(None)
    pooled = tokens.start(walk, 3, sampling, 8, allow_end=False)
    own = generator.tokens.start(walk, 3, sampling, 8, allow_end=False)
    monkeypatch.setattr(TokenGenerator, "run", counted)
    for n in range(20):
        assert np.array_equal(pooled.step(), own.step()), f"step {n}"
    assert len(on_exported) == 20 * generator.tokens.num_levels and all(on_exported)
    bucket, row = tokens.pool.place[id(pooled)]
    held = len(own.positions)
    for level, cache in enumerate(own.caches):
        for array, slots in zip(bucket.arrays[level], cache, strict=True):
            assert np.array_equal(array[row : row + 1, :, :held], slots)


def test_a_bucket_grown_past_its_rows_keeps_every_streams_slots(
    generator, engine_parts, monkeypatch
):
    """A bucket made with fewer rows than its streams (mogo.kv_pool.ROWS) grows, the slots of
    its rows copied along: every stream draws on as on its own cache."""
    monkeypatch.setattr(kv_pool, "ROWS", 2)
    sampling = generator.sampling(None)
    prompts = generator.embed(["a person walks forward.", "a person waves.", "a person jumps."])
    tokens = engine_parts.with_own_pool()
    pooled, own = [], []
    for n in range(12):
        if n in (0, 4, 6):  # the third stream grows the bucket past two rows of slots
            seed = len(pooled)
            pooled.append(tokens.start(prompts[seed], seed, sampling, None, allow_end=False))
            own.append(generator.tokens.start(prompts[seed], seed, sampling, None, False))
        for row, stream in zip(step_together(pooled), own, strict=True):
            assert np.array_equal(row, stream.step()), f"step {n}"
    assert [len(bucket.positions) for bucket in tokens.pool.buckets.values()] == [4]


def test_a_pooled_call_writes_each_rows_new_slot_into_the_pasts_it_reads(engine_parts):
    """The stages read the pasts they are given, in place: each row's new key and value land
    at its `slots` before the next layer reads them, and no other slot changes."""
    layers, heads, head_dim = engine_parts.cache_shapes[0]
    prompt = np.random.default_rng(0).standard_normal((2, 128)).astype(np.float32)
    slots = np.array([[1], [3]])  # row 0 holds the prefix alone, row 1 three slots
    keys = np.full((2, 8), 2**62)  # MASKED past each row's slots
    keys[0, :2], keys[1, :4] = [0, 1], [0, 1, 2, 3]
    past = [np.full((2, heads, 8, head_dim), 0.5, np.float32) for _ in range(2 * layers)]
    before = [p.copy() for p in past]
    ids = np.zeros((2, 1, engine_parts.num_levels), np.int64)
    _, presents = engine_parts.run(0, prompt, np.zeros(2, bool), ids, slots, keys, past, slots)
    for held, was, new in zip(past, before, presents, strict=True):
        for row, slot in enumerate(slots[:, 0]):
            assert np.array_equal(held[row, :, slot], new[row, :, 0])
            held[row, :, slot] = was[row, :, slot]
        assert np.array_equal(held, was)  # nothing else written


def test_a_graph_the_server_cannot_pool_is_refused_in_one_line(generator):
    from mogo.manifest import BundleError
    from mogo.serve.pooled import pooled_stages

    with pytest.raises(BundleError, match="vq_decoder.onnx: not a level graph the server can "):
        pooled_stages(generator.bundle.path(generator.manifest.vq.decoder.file))


def test_signed_weights_give_the_numbers_of_unsigned_ones(generator):
    """Where this CPU's onnxruntime multiplies uint8 by int8 exactly, the row-wise level graphs
    hold their weights as int8 (faster products): the same outputs, bit for bit."""
    import onnx

    from mogo._session import cpu_session
    from mogo.serve.rowwise import rowwise_graph, signed_products_exact

    if not signed_products_exact():
        pytest.skip("this CPU's onnxruntime saturates uint8 x int8 products: weights stay uint8")
    path = generator.bundle.path(generator.manifest.t2m.levels[2].file)
    graphs = {signed: rowwise_graph(path, signed) for signed in (False, True)}
    for signed, graph in graphs.items():
        model = onnx.load_from_string(graph).graph
        initializers = {init.name: init.data_type for init in model.initializer}
        weights = {
            initializers[node.input[1]] for node in model.node if node.op_type == "MatMulInteger"
        }
        assert weights == {onnx.TensorProto.INT8 if signed else onnx.TensorProto.UINT8}
    rng = np.random.default_rng(0)
    rows, slots = 5, 7
    session = cpu_session(graphs[False])
    feed = {}
    for arg in session.get_inputs():
        if arg.name == "prompt":
            feed[arg.name] = rng.standard_normal((rows, arg.shape[1])).astype(np.float32)
        elif arg.name == "uncond":
            feed[arg.name] = np.zeros(rows, bool)
        elif arg.name == "token_ids":
            feed[arg.name] = rng.integers(0, 512, (rows, 1, arg.shape[2]))
        elif arg.name == "positions":
            feed[arg.name] = np.array([slots])
        elif arg.name == "past_positions":
            feed[arg.name] = np.arange(slots)
        else:  # a past key or value (rows, heads, slots, head_dim)
            shape = (rows, arg.shape[1], slots, arg.shape[3])
            feed[arg.name] = rng.standard_normal(shape).astype(np.float32)
    unsigned, signed = (cpu_session(graphs[s]).run(None, feed) for s in (False, True))
    assert all(np.array_equal(a, b) for a, b in zip(unsigned, signed, strict=True))
