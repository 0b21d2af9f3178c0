"""One KV cache for many token streams: rows of shared arrays, so streams at any step share a call.

The level graphs of `mogo serve` (mogo.serve.pooled) take each row's own positions and return
only the new slots. A pool keeps every stream's cache as one row of preallocated arrays, its
slots in the order the stream's own cache would hold them (TokenStream.positions); the slots
past them hold MASKED positions, which the graphs mask out. A call reads the rows where they
lie (a contiguous run of rows is passed without a copy, and read in place: StagedSession) and
each stream's new slot is written into its row in place.

Rows are kept in buckets by capacity (SLOTS, 2 SLOTS, ...): a call reads all the slots of its
bucket, so a stream 5 steps into a clip does not pay for another's 80. A stream whose cache
outgrows its bucket moves to the next one (one row copied); a restart moves it back.
"""

from __future__ import annotations

import mmap
from collections.abc import Sequence

import numpy as np

from mogo._session import cpu_session
from mogo.manifest import Graph

MASKED = 2**62  # a slot's position after any query's: the graphs mask it out
SLOTS = 32  # bucket capacities are multiples of this
ROWS = 256  # rows a bucket is made with: its arrays take memory only as rows are written
# (`_zeros`), while growing copies every row held, a stall of every stream (0.1-0.5 s from
# 64 or 128 rows)


class StagedSession:
    """A pooled level graph's stages (mogo.serve.pooled) run as one graph: after the stage that
    makes a layer's new key and value slots, they are written into the pasts the call was
    given, at `slots` (right after each row's own), where the later stages read them. So a call
    reads its rows of the pool in place: a graph that wrote them itself would copy every slot
    it reads, each call (a ScatterElements: 42% of a call at 88 rows of 64 slots)."""

    def __init__(self, stages: Sequence[bytes], graph: Graph, intra_op_threads: int = 1):
        """stages: serialised graphs, in order; graph: the pooled graph's names by role (the
        presents are outputs 1..n, their pasts the n inputs before the last, `slots`)."""
        self.stages = [cpu_session(stage, intra_op_threads) for stage in stages]
        self._io = [
            ([arg.name for arg in s.get_inputs()], [arg.name for arg in s.get_outputs()])
            for s in self.stages
        ]
        presents = graph.outputs[1:]
        self._slots = graph.inputs[-1]
        self._past_of = dict(zip(presents, graph.inputs[-1 - len(presents) : -1], strict=True))
        args = {arg.name: arg for stage in self.stages for arg in stage.get_inputs()}
        self._inputs = [args[name] for name in graph.inputs if name in args]

    def get_inputs(self) -> list:
        """The graph inputs the stages read (onnxruntime's NodeArgs), in the graph's order."""
        return self._inputs

    def run(self, output_names: Sequence[str], feed: dict[str, np.ndarray]) -> list[np.ndarray]:
        """onnxruntime's InferenceSession.run; the pasts in `feed` are written in place (each
        row's new slots at its `slots`)."""
        values = dict(feed)
        slots = feed[self._slots]  # (batch, seq)
        rows = np.arange(len(slots))[:, None]
        for session, (inputs, outputs) in zip(self.stages, self._io, strict=True):
            results = session.run(outputs, {name: values[name] for name in inputs})
            values.update(zip(outputs, results, strict=True))
            for name, new in zip(outputs, results, strict=True):
                if name in self._past_of:  # new (batch, heads, seq, head_dim)
                    values[self._past_of[name]][rows, :, slots] = new.transpose(0, 2, 1, 3)
        return [values[name] for name in output_names]


class KVPool:
    """The caches of the streams of one TokenGenerator (with pooled graphs), one row each."""

    def __init__(self, cache_shapes: Sequence[tuple[int, int, int]]):
        """cache_shapes[l]: (layers, heads, head_dim) of level l."""
        self.cache_shapes = list(cache_shapes)
        self.buckets: dict[int, _Bucket] = {}
        self.place: dict[int, tuple[_Bucket, int]] = {}  # id(stream) -> its bucket and row

    def __len__(self) -> int:
        return len(self.place)

    def store(self, stream, caches: list[list[np.ndarray]] | None) -> None:
        """Set a stream's whole cache: `caches[l]` (1, heads, n, head_dim) per layer's key and
        value, its slots at stream.positions (n of them); None: no slot (a fresh clip)."""
        n = len(stream.positions)
        bucket, row = self._move(stream, _capacity(n + 1))  # room for the next step
        if caches is not None:
            for arrays, level in zip(bucket.arrays, caches, strict=True):
                for array, cache in zip(arrays, level, strict=True):
                    array[row, :, :n] = cache[0]
        bucket.positions[row] = MASKED
        bucket.positions[row, :n] = stream.positions

    def caches(self, stream) -> list[list[np.ndarray]]:
        """A stream's whole cache, as `store` takes it (a copy)."""
        bucket, row = self.place[id(stream)]
        n = len(stream.positions)
        return [[array[row : row + 1, :, :n].copy() for array in level] for level in bucket.arrays]

    def remove(self, stream) -> None:
        """Free a stream's row (the last row of its bucket takes its place)."""
        where = self.place.pop(id(stream), None)
        if where is not None:
            moved = where[0].pop(where[1])
            if moved is not None:
                self.place[id(moved)] = where

    def groups(self, streams: Sequence) -> list[tuple[_Bucket, list[int], slice | np.ndarray]]:
        """The streams (indices into `streams`) by bucket, each with the rows they occupy: a
        slice where they are a run of rows in order (read without a copy)."""
        by_bucket: dict[int, list[int]] = {}
        for k, stream in enumerate(streams):
            by_bucket.setdefault(self.place[id(stream)][0].capacity, []).append(k)
        out = []
        for capacity, ks in sorted(by_bucket.items()):
            rows = np.array([self.place[id(streams[k])][1] for k in ks])
            order = np.argsort(rows, kind="stable")
            ks, rows = [ks[i] for i in order], rows[order]
            run = rows[-1] - rows[0] + 1 == len(rows)
            out.append((self.buckets[capacity], ks, slice(rows[0], rows[-1] + 1) if run else rows))
        return out

    def reserve(self, stream, slots: int) -> None:
        """Room for `slots` slots in the stream's row (a larger bucket where it has not)."""
        if slots > self.place[id(stream)][0].capacity:
            self._move(stream, _capacity(slots))

    def write(
        self,
        streams: Sequence,
        slots: Sequence[int],
        new: list[list[np.ndarray]],
        written: Sequence[bool] | None = None,
    ) -> None:
        """After a call: stream k's new slot, `new[l][i][k]` (heads, 1, head_dim) per level and
        layer, into `slots[k]` of its row, at the position the stream gave it. written[k]: the
        call read stream k's row in place and wrote the slot there already (its position
        alone is set)."""
        if not streams:
            return
        buckets: dict[int, list[int]] = {}
        for k, stream in enumerate(streams):
            buckets.setdefault(id(self.place[id(stream)][0]), []).append(k)
        slots = np.asarray(slots)
        for ks in buckets.values():
            bucket = self.place[id(streams[ks[0]])][0]
            rows = np.array([self.place[id(streams[k])][1] for k in ks])
            at = slots[ks]
            bucket.positions[rows, at] = [streams[k].positions[slots[k]] for k in ks]
            copied = [i for i, k in enumerate(ks) if written is None or not written[k]]
            if copied:
                ks, rows, at = [ks[i] for i in copied], rows[copied], at[copied]
                for arrays, level in zip(bucket.arrays, new, strict=True):
                    for array, present in zip(arrays, level, strict=True):
                        array[rows, :, at] = present[ks, :, -1]

    def _move(self, stream, capacity: int) -> tuple[_Bucket, int]:
        """Give `stream` a row in the bucket of `capacity`, its live slots copied along."""
        bucket = self.buckets.get(capacity)
        if bucket is None:
            bucket = self.buckets[capacity] = _Bucket(capacity, self.cache_shapes)
        where = self.place.get(id(stream))
        if where is not None and where[0] is bucket:
            return where
        row = bucket.add(stream)
        if where is not None:
            old, old_row = where
            n = min(len(stream.positions), old.capacity, capacity)
            for arrays, old_arrays in zip(bucket.arrays, old.arrays, strict=True):
                for array, old_array in zip(arrays, old_arrays, strict=True):
                    array[row, :, :n] = old_array[old_row, :, :n]
            bucket.positions[row, :n] = old.positions[old_row, :n]
            self.remove(stream)
        self.place[id(stream)] = (bucket, row)
        return bucket, row


class _Bucket:
    """Rows of one capacity: per level and layer a key or value array (rows, heads, capacity,
    head_dim), the slots' positions (rows, capacity), the stream of each row."""

    def __init__(self, capacity: int, cache_shapes: Sequence[tuple[int, int, int]]):
        self.capacity, self.cache_shapes = capacity, cache_shapes
        self.members: list = []
        self._allocate(ROWS)

    def _allocate(self, rows: int) -> None:
        old = getattr(self, "arrays", None)
        self.arrays = [
            [_zeros((rows, heads, self.capacity, head_dim)) for _ in range(2 * layers)]
            for layers, heads, head_dim in self.cache_shapes
        ]
        positions = np.full((rows, self.capacity), MASKED, np.int64)
        if old is not None:
            n = len(self.members)
            for arrays, old_arrays in zip(self.arrays, old, strict=True):
                for array, old_array in zip(arrays, old_arrays, strict=True):
                    array[:n] = old_array[:n]
            positions[:n] = self.positions[:n]
        self.positions = positions

    def add(self, stream) -> int:
        if len(self.members) == len(self.positions):
            self._allocate(2 * len(self.positions))
        self.members.append(stream)
        row = len(self.members) - 1
        self.positions[row] = MASKED
        return row

    def pop(self, row: int):
        """Free `row`: the last row moves into it; returns the stream moved (None if none)."""
        last = len(self.members) - 1
        moved = None
        if row != last:
            for arrays in self.arrays:
                for array in arrays:
                    array[row] = array[last]
            self.positions[row] = self.positions[last]
            moved = self.members[row] = self.members[last]
        self.members.pop()
        return moved


def _zeros(shape: tuple[int, ...]) -> np.ndarray:
    """float32 zeros in anonymous memory, taken page by page as they are written, in small
    pages: where the system backs memory with 2 MB pages (Linux's transparent huge pages),
    numpy's zeros of ROWS rows took 2 MB of every array for a stream's first slot."""
    count = int(np.prod(shape))
    buffer = mmap.mmap(-1, max(1, 4 * count))
    if hasattr(mmap, "MADV_NOHUGEPAGE"):
        buffer.madvise(mmap.MADV_NOHUGEPAGE)
    return np.frombuffer(buffer, np.float32, count).reshape(shape)


def _capacity(slots: int) -> int:
    return max(SLOTS, -(-slots // SLOTS) * SLOTS)
