"""The compiled runtime of one noise pipeline (:class:`Pipeline`) and its public fused view (:class:`NoiseBlock`).

:class:`~noise_models.corruptor.SignalCorruptor` owns the pipelines; this module is how one of them runs: consecutive
additive and multiplicative processes fused into one affine map per step whose noise is pre-drawn in blocks of
``BLOCK`` steps, then the pipeline's clip.

Example:
    >>> import numpy as np
    >>> from noise_models import Gaussian, ObservationNoise
    >>> from noise_models.corruptor import SignalCorruptor
    >>> from noise_models.values import Layout
    >>> c = SignalCorruptor([ObservationNoise(Gaussian(std=0.1))], seed=0)
    >>> c.bind(obs=Layout(3), action=None, timestep=0.01, substeps=1)
    >>> c.begin_episode()
    >>> block = c.noise_blocks("observation")[0]
    >>> block.offsets.shape[1], block.gain is None, block.low is None
    (3, True, True)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from noise_models.parts import BLOCK, Compile, Part
from noise_models.pipelines import ActionNoise, ObservationNoise
from noise_models.values import Layout, selection_repr

if TYPE_CHECKING:
    from noise_models.corruptor import SignalCorruptor

__all__ = ["NoiseBlock", "Pipeline", "compose", "hot_pipe", "next_blocks", "pipeline_of"]


# -- compiled runtime --------------------------------------------------------------------------


try:  # the clip ufunc itself: np.clip's Python dispatch costs more than the clipping
    # numpy's stubs do not declare the `clip` ufunc in umath, though numpy 2 exports it there.
    from numpy._core.umath import clip as _clip  # type: ignore[attr-defined]
except ImportError:  # pragma: no cover - numpy < 2
    from numpy.core.umath import clip as _clip  # type: ignore[no-redef]


class _Affine:
    """Consecutive gain/offset/noise parts fused into ``x * G + F[r]`` with ``F`` drawn per block."""

    def __init__(self, parts: list[Part], size: int, dtype: np.dtype) -> None:
        self.parts = parts
        self.size = size
        self.dtype = dtype
        self.F = np.zeros((BLOCK, size), dtype=dtype)
        self.G: np.ndarray | None = None
        self.rows: list[np.ndarray] = []
        # The step's rows: views made once into a buffer each block is cast into (``refill(rows=True)``; handed on
        # to the next episode's stage by Pipeline.begin), since 256 fresh views per block cost as much as its draws.
        self._buf: np.ndarray | None = None
        self._buf_rows: list[np.ndarray] = []
        self._plan: tuple[Any, ...] | None = None  # see plan: made by Pipeline.begin

    def plan(self) -> None:
        """Sets ``_plan``, read by :func:`next_blocks`: ``(Philox key, episode, scale, bias rows or None)`` when this stage is the usual signal noise, a Gaussian of a keyed
        stream over every entry (``_Block.normals``) then at most one offset over every entry (a Bias), drawn and
        summed in one pass with no Python call per world; None otherwise. Called once the episode's parts are in."""
        plan = None
        parts, whole = self.parts, slice(0, self.size)
        head = parts[0]
        normals = getattr(head, "normals", None) if head.kind == "block" else None
        if normals is not None and type(head.sel) is slice and head.sel == whole and len(parts) <= 2:
            if len(parts) == 1:
                plan = (*normals, None)
            else:
                bias = parts[1]
                if bias.kind == "add" and type(bias.sel) is slice and bias.sel == whole:
                    plan = (*normals, bias.rows())  # type: ignore[attr-defined]
        self._plan = plan

    def refill(self, block: int, rows: bool = True) -> None:
        F = np.empty((BLOCK, self.size))
        compose(self.parts, block, F)
        G = np.ones(self.size)
        for p in self.parts:
            if p.kind == "gain":
                G[p.sel] *= p.gain  # type: ignore[attr-defined]
        if rows:
            buf = self._buf
            if buf is None:
                buf = self._buf = np.empty((BLOCK, self.size), dtype=self.dtype)
                self._buf_rows = list(buf)
            buf[...] = F  # astype's cast, into the buffer the step's row views look at
            self.F = buf
            self.rows = self._buf_rows
        else:
            # Code that reads F whole (NoiseBlock: the batched engine) gets a block of its own and no row views.
            self.F = F.astype(self.dtype)
            self.rows = []
        self.G = None if bool((G == 1.0).all()) else G.astype(self.dtype)

    def apply(self, x: np.ndarray, r: int) -> np.ndarray:
        if self.G is None:
            return x + self.rows[r]
        w = x * self.G
        w += self.rows[r]
        return w


class Pipeline:
    """One pipeline of a :class:`~noise_models.corruptor.SignalCorruptor`, compiled for its layout and dtype."""

    def __init__(
        self,
        noise: ObservationNoise | ActionNoise,
        names: list[str],
        layout: Layout,
        dtype: np.dtype,
        streams_ref: SignalCorruptor,
    ) -> None:
        self.noise = noise
        self.names = names
        self.layout = layout
        self.dtype = dtype
        self.owner = streams_ref
        self.selects = [p.select if p.select is not None else noise.select for p in noise.processes]
        self.indices = [layout.resolve(s, "select") for s in self.selects]
        self.gens: list[np.random.Generator] = [streams_ref._streams.generator(n) for n in names]
        self.stages: list[Any] = []
        self.r = BLOCK
        self.block = -1
        self.simple = 0
        self._scratch: np.random.Generator | None = None
        self._f64: np.ndarray | None = None  # the float64 block _refill_planned draws into
        #: The scratch generator's state as _refill_planned writes it (key and counter filled in per block).
        self._scratch_state: dict[str, Any] = {
            "bit_generator": "Philox",
            "state": {"counter": [0, 0, 0, 0], "key": []},
            "buffer": [0, 0, 0, 0],
            "buffer_pos": 4,
            "has_uint32": 0,
            "uinteger": 0,
        }
        self.rows: list[np.ndarray] = []  # the single affine stage's rows when ``simple``
        #: The episode's :meth:`_Affine.plan` when the pipeline is that one stage (the usual noise), else None: read
        #: by :func:`next_blocks` from the pipeline itself, so a refill of many worlds looks at no stage.
        self.plan: tuple[Any, ...] | None = None
        clip = noise.clip and layout.low is not None
        # Bounds in the signal's dtype: mixed-dtype ufuncs take numpy's slow casting path.
        low = np.asarray(layout.low, dtype=dtype) if clip else None
        high = np.asarray(layout.high, dtype=dtype) if clip else None
        # Observations: only the entries some process selects are clipped, and only where the env's own
        # value lies inside the bounds (see ObservationNoise); actions are clipped whole to the actuators' range.
        self.guard = isinstance(noise, ObservationNoise)
        if clip and self.guard:
            chosen = np.zeros(layout.size, dtype=bool)
            for idx in self.indices:
                chosen[idx] = True
            low = np.where(chosen, low, -np.inf).astype(dtype)  # type: ignore[arg-type]
            high = np.where(chosen, high, np.inf).astype(dtype)  # type: ignore[arg-type]
            if not (np.isfinite(low).any() or np.isfinite(high).any()):
                low = high = None
        self.low, self.high = low, high

    def scratch_generator(self) -> np.random.Generator:
        """A Philox generator of this pipeline's own, made at the first call, that :func:`next_blocks` sets to each
        world's stream state in turn and :meth:`_refill_planned` to this pipeline's (it never holds a stream of its
        own between calls); ``_scratch_state`` is the state dict both write the key and counter into."""
        gen = self._scratch
        if gen is None:
            gen = self._scratch = np.random.Generator(np.random.Philox(key=np.zeros(2, np.uint64)))
        return gen

    def regenerate(self) -> None:
        """New generators after the streams were re-rooted (``reset(seed=...)``)."""
        self.gens = [self.owner._streams.generator(n) for n in self.names]

    def begin(self, episode: int, report: dict[str, float]) -> None:
        streams = self.owner._streams
        parts: list[Part] = []
        for proc, name, gen, idx, select in zip(
            self.noise.processes, self.names, self.gens, self.indices, self.selects, strict=True
        ):
            streams.start(gen, name, episode, 0)

            def block_rng(b: int, gen: np.random.Generator = gen, name: str = name) -> np.random.Generator:
                streams.start(gen, name, episode, 1 + b)
                return gen

            prefix = name.partition("[")[0]  # reports use the plain name: obs_noise_std[3]
            stream = (streams.philox_key(name), episode)
            ctx = Compile(proc, prefix, self.layout, idx, gen, block_rng, report, selection_repr(select), stream)
            parts.append(proc.compile(ctx))
        stages: list[Any] = []
        for part in parts:
            if part.kind == "op":
                stages.append(part)
            elif stages and isinstance(stages[-1], _Affine):
                stages[-1].parts.append(part)
            else:
                stages.append(_Affine([part], self.layout.size, self.dtype))
        for old, new in zip(self.stages, stages, strict=False):
            if isinstance(old, _Affine) and isinstance(new, _Affine):  # the rows' buffer outlives the episode
                new._buf, new._buf_rows = old._buf, old._buf_rows
        for stage in stages:
            if isinstance(stage, _Affine):
                stage.plan()
        self.plan = stages[0]._plan if len(stages) == 1 and isinstance(stages[0], _Affine) else None
        self.stages = stages
        self.first_affine = isinstance(stages[0], _Affine)
        self.simple = 0  # decided after the first refill, when the gain is known (see _decide)
        self.block = -1
        self.r = BLOCK

    def _decide(self) -> None:
        stage = self.stages[0]
        plain = self.first_affine and len(self.stages) == 1 and stage.G is None
        # 1: add; 2: add, then clip whole (actions); 3: add, then the guarded clip (observations).
        self.simple = (1 if self.low is None else 3 if self.guard else 2) if plain else 0
        self.rows = stage.rows if plain else []

    def refill(self, rows: bool = True) -> None:
        """Draws the next block (``rows=False``: without the per-row views the step's add reads, for a
        :meth:`noise_block` reader that takes the offsets whole and steps them itself)."""
        self.block += 1
        plan = self.plan
        if plan is not None and rows:
            self._refill_planned(plan)
        else:
            for stage in self.stages:
                if isinstance(stage, _Affine):
                    stage.refill(self.block, rows)
                else:
                    stage.refill(self.block)
        self.r = 0
        self._decide()

    def _refill_planned(self, plan: tuple[Any, ...]) -> None:
        """:meth:`refill` of the usual noise (:attr:`plan`: one Gaussian of a keyed stream over every entry, then at
        most one Bias over every entry): the scratch generator set to the stream's key and counter draws into a
        float64 array of this pipeline's own, scaled and biased, then cast into the rows' buffer. The values of
        :func:`compose` then the cast (see :func:`_compose_additive`, which draws many worlds' blocks this way), with
        no part, closure or stream lookup per block: a refill runs once every ``BLOCK`` steps with cold caches, where
        its Python calls cost about three times what they cost in a loop."""
        stage = self.stages[0]
        key, episode, scale, bias = plan
        F = self._f64
        if F is None:
            F = self._f64 = np.empty((BLOCK, self.layout.size))
        gen = self.scratch_generator()
        state = self._scratch_state
        state["state"]["key"] = key  # StreamFactory.start(gen, name, episode, 1 + block), on the scratch generator
        counter = state["state"]["counter"]
        counter[2] = 1 + self.block
        counter[3] = episode
        gen.bit_generator.state = state  # (numpy copies it in: the dict stays reusable)
        gen.standard_normal(out=F)
        F *= scale
        if bias is not None:
            np.add(F, bias, F)
        buf = stage._buf
        if buf is None:
            buf = stage._buf = np.empty((BLOCK, self.layout.size), dtype=self.dtype)
            stage._buf_rows = list(buf)
        np.add(F, 0.0, out=buf)  # compose's + 0.0, then astype's cast
        stage.F = buf
        stage.rows = stage._buf_rows
        stage.G = None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        r = self.r
        if r == BLOCK:
            self.refill()
            r = 0
        self.r = r + 1
        simple = self.simple
        if simple:  # one fused affine stage (no gain): one add per step, then the clip if any
            w = x + self.rows[r]
            if simple == 2:
                _clip(w, self.low, self.high, out=w)
            elif simple == 3:
                self._clip(x, w)
            return w
        if self.first_affine:
            w = self.stages[0].apply(x, r)
            rest = self.stages[1:]
        else:
            w = np.array(x, dtype=self.dtype)
            rest = self.stages
        for stage in rest:
            if isinstance(stage, _Affine):
                w = stage.apply(w, r)
            else:
                stage.apply(w, r)
        if self.low is not None:
            self._clip(x, w)
        return w

    def noise_block(self) -> NoiseBlock:
        """This pipeline as one :class:`NoiseBlock` (its current block; raises ValueError when it is not one
        affine stage)."""
        if len(self.stages) != 1 or not isinstance(self.stages[0], _Affine):
            raise ValueError(f"`{self.names[0]}`: the pipeline is not one affine stage (see NoiseBlock).")
        stage = self.stages[0]
        F = stage.F.copy() if stage.F is stage._buf else stage.F  # the step's buffer is overwritten next block
        return NoiseBlock(F, stage.G, self.r, self.low, self.high, self.guard)

    def _clip(self, x: np.ndarray, w: np.ndarray) -> None:
        low, high = self.low, self.high
        if not self.guard:
            _clip(w, low, high, out=w)
            return
        np.copyto(w, _clip(w, low, high), where=(x >= low) & (x <= high))


def pipeline_of(corruptor: SignalCorruptor, side: str, k: int) -> Pipeline:
    """The ``k``-th ``side`` pipeline of a bound ``corruptor``, the one
    :meth:`~noise_models.corruptor.SignalCorruptor.next_noise_blocks` refills: for code that refills the same
    pipelines many times (the batched engine's worlds) and looks them up once, then calls :func:`next_blocks`. A
    corruptor's pipelines are made when it is bound; look them up again after that."""
    return corruptor._pipes(side)[k]


def next_blocks(
    pipes: Sequence[Pipeline], out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The next block of each of ``pipes`` (one affine stage each, of the same processes: the worlds of one batched
    engine), each drawn from its own streams as its own refill would, composed for all pipelines at once.

    The same per-element arithmetic as :meth:`Pipeline.refill` then :meth:`Pipeline.noise_block` one pipeline at a
    time (zeros, then each part's ``*=`` or ``+=`` in order, then the cast to the signal's dtype), composed one
    pipeline at a time in one small float64 array that stays in cache and cast straight into the pipeline's rows of
    the result: one ``(P, BLOCK, size)`` float64 composition was several passes over memory the physics step had just
    evicted, and cost more than the per-pipeline calls. Each pipeline counts its block as handed over, as
    ``SignalCorruptor.next_noise_block`` does: its own next step draws the block after it.

    Args:
        pipes: the pipelines.
        out: ``(offsets, gains, unit)`` arrays of the returned shapes and dtypes (any strides) to write the result
            into and return, e.g. the batched engine's own blocks: no ``(P, BLOCK, size)`` array is allocated.

    Returns:
        ``(offsets, gains, unit)``: ``(P, BLOCK, size)`` offsets and ``(P, size)`` gains in the signal's dtype (a
        pipeline without gain: ones), and ``(P,)`` bool, True where a pipeline has no gain (``NoiseBlock.gain`` None).
    """
    plans = [pipe.plan for pipe in pipes]
    if None not in plans:  # the usual noise in every pipeline (no gain): one pass a world, no stage looked at
        lead = pipes[0]
        n, size = len(pipes), lead.layout.size
        if out is None:
            out = (np.empty((n, BLOCK, size), lead.dtype), np.empty((n, size), lead.dtype), np.empty(n, bool))
        _compose_additive((), pipes, out[0], plans)  # type: ignore[arg-type]
        out[1][...] = 1.0
        out[2][...] = True
        return out
    stages: list[_Affine] = []
    for pipe in pipes:
        if len(pipe.stages) != 1 or not isinstance(pipe.stages[0], _Affine):
            raise ValueError(f"`{pipe.names[0]}`: the pipeline is not one affine stage (see NoiseBlock).")
        pipe.block += 1
        pipe.r = BLOCK  # handed over, as next_noise_block
        stages.append(pipe.stages[0])
    first = stages[0]
    n = len(stages)
    G = np.ones((n, first.size))
    additive = True
    for j, part in enumerate(first.parts):
        if part.kind == "gain":  # a scalar or one value per selected entry: (n, 1) or (n, k), as each refill has it
            G[:, part.sel] *= np.stack([s.parts[j].gain for s in stages]).reshape(n, -1)  # type: ignore[attr-defined]
            additive = False
    if out is None:
        out = (np.empty((n, BLOCK, first.size), first.dtype), np.empty((n, first.size), first.dtype), np.empty(n, bool))
    offsets, gains, unit = out
    if additive:
        _compose_additive(stages, pipes, offsets)
    else:
        F = np.empty((BLOCK, first.size))
        for i, (stage, pipe) in enumerate(zip(stages, pipes, strict=True)):
            compose(stage.parts, pipe.block, F)
            offsets[i] = F  # astype's cast
    np.copyto(gains, G)
    np.all(G == 1.0, axis=1, out=unit)
    return out


#: Bytes of float64 offsets :func:`_compose_additive` composes before casting them: a few pipelines' blocks, small
#: enough to stay in cache from their draws to their cast.
_CHUNK_BYTES = 3 << 15


def _compose_additive(
    stages: Sequence[_Affine],
    pipes: Sequence[Pipeline],
    offsets: np.ndarray,
    plans: Sequence[tuple[Any, ...]] | None = None,
) -> None:
    """:func:`compose` of stages without gain parts, then the cast into ``offsets`` (``(P, BLOCK, size)``), a few
    pipelines at a time: each pipeline's draws and sums in its own ``(BLOCK, size)`` slice of a float64 scratch
    array, then one ``+ 0.0`` that casts them all into ``offsets``.

    :func:`compose` adds ``0.0`` to a first process's draws before the other parts' sums; here it comes after them:
    the same floats, since ``(x + 0.0) + b == (x + b) + 0.0`` for all finite ``x`` and ``b`` (adding ``0.0`` only
    turns ``-0.0`` into ``0.0``, and ``x + b`` is ``-0.0`` only when both are). A gain part breaks this (the sign of
    ``0.0 * g``), so stages with one take :func:`compose` (``next_blocks``).

    ``plans``: every pipeline's :attr:`Pipeline.plan` (the usual noise), read instead of ``stages``; each pipeline's
    block is counted here then (``block += 1``, ``r = BLOCK``, as :func:`next_blocks` does before the other path).
    """
    size = offsets.shape[2]
    chunk = max(1, _CHUNK_BYTES // (BLOCK * size * 8))
    n = len(pipes)
    scratch = np.empty((min(chunk, n), BLOCK, size))
    # A row of 8 contiguous bytes (two float32: actions of two actuators): cast contiguously into a float32 chunk,
    # then moved as int64 (the same bits) in ``offsets``' order: numpy's cast into rows of two floats spread over the
    # engine's (BLOCK, N, size) blocks walks them 2 at a time (2x slower).
    item = offsets.dtype.itemsize
    paired = item * size == 8 and offsets.strides[2] == item
    if paired:
        bits = offsets.view(np.int64)[:, :, 0]  # (P, BLOCK): each row's two floats as one int64
        cast = np.empty(scratch.shape, offsets.dtype)
        cast_bits = cast.view(np.int64)[:, :, 0]
    # The usual noise (a Gaussian of a keyed stream, then a Bias: _Affine.plan): each world's stream drawn inline by
    # one generator set to its state (key and counter: the values do not depend on which generator draws them),
    # scaled and biased while its block is in cache: draw_into's and the sum's values, with no Python call a world
    # but numpy's, and one generator object in cache instead of one a world.
    inline = plans is not None
    if inline:
        gen = pipes[0].scratch_generator()
        bitgen, normal = gen.bit_generator, gen.standard_normal
        # One state dict for every world (numpy copies it in): each world's key and counter written into it in turn.
        state = pipes[0]._scratch_state
        inner = state["state"]
        counter = inner["counter"]
    else:
        head = stages[0].parts[0]
        drawn = head.kind == "block" and getattr(head, "draw_into", None) is not None
        drawn = drawn and isinstance(head.sel, slice) and head.sel == slice(0, size)
    whole = slice(0, size)
    for start in range(0, n, chunk):
        stop = min(start + chunk, n)
        F = scratch[: stop - start]
        if inline:
            for f, plan, pipe in zip(F, plans[start:stop], pipes[start:stop], strict=True):  # type: ignore[index]
                b = pipe.block + 1
                pipe.block = b
                pipe.r = BLOCK  # handed over, as next_noise_block
                key, episode, scale, bias = plan
                inner["key"] = key  # StreamFactory.start(gen, name, episode, 1 + block), on our generator
                counter[2] = 1 + b
                counter[3] = episode
                bitgen.state = state
                normal(out=f)
                f *= scale
                if bias is not None:
                    np.add(f, bias, f)
        else:
            if not drawn:
                F.fill(0.0)
            for f, stage, pipe in zip(F, stages[start:stop], pipes[start:stop], strict=True):
                parts = stage.parts
                b = pipe.block
                if drawn:
                    parts[0].draw_into(b, f)  # type: ignore[attr-defined]
                    parts = parts[1:]
                for part in parts:
                    if part.kind == "add":
                        if type(part.sel) is slice and part.sel == whole:
                            np.add(f, part.rows(), f)  # type: ignore[attr-defined]
                        else:
                            f[:, part.sel] += part.rows()  # type: ignore[attr-defined]
                    else:
                        f[:, part.sel] += part.block(b)  # type: ignore[attr-defined]
        if paired:
            np.add(F, 0.0, F)  # compose's + 0.0
            m = stop - start
            np.copyto(cast[:m], F)  # astype's cast
            np.copyto(bits[start:stop], cast_bits[:m])
        else:
            np.add(F, 0.0, out=offsets[start:stop])  # compose's + 0.0, then astype's cast


def compose(parts: Sequence[Part], block: int, F: np.ndarray) -> None:
    """Writes block ``block`` of one affine stage's offsets into the float64 ``(BLOCK, size)`` array ``F``: zeros,
    then each part's ``*=`` (gain) or ``+=`` (offset rows, per-step draws) in order. A first process that draws every
    entry and can draw into an array (``draw_into``) draws straight into ``F``, then ``+ 0.0`` (what the zeros it is
    added to would give: -0.0 becomes 0.0), instead of zeros, an array of draws and a sum: the same values."""
    head = parts[0]
    draw_into = getattr(head, "draw_into", None) if head.kind == "block" else None
    if draw_into is not None and isinstance(head.sel, slice) and head.sel == slice(0, F.shape[1]):
        draw_into(block, F)
        F += 0.0
        parts = parts[1:]
    else:
        F.fill(0.0)
    for part in parts:
        if part.kind == "gain":
            F[:, part.sel] *= part.gain  # type: ignore[attr-defined]
        elif part.kind == "add":
            F[:, part.sel] += part.rows()  # type: ignore[attr-defined]
        else:
            F[:, part.sel] += part.block(block)  # type: ignore[attr-defined]


def hot_pipe(pipe: Pipeline) -> Callable[[np.ndarray], np.ndarray]:
    """``pipe`` as one function for the step's hot path: the same state (row counter, blocks) and the same
    arithmetic as calling ``pipe``, with the one-add case (the common one: Gaussian, Bias, Drift...) inlined
    instead of dispatched per step."""
    low, high = pipe.low, pipe.high

    def apply(x: np.ndarray) -> np.ndarray:
        r = pipe.r
        simple = pipe.simple
        if r == BLOCK or not simple:  # a new block (simple is decided at its refill) or more than one add
            return pipe(x)
        pipe.r = r + 1
        w = x + pipe.rows[r]
        if simple == 2:
            _clip(w, low, high, w)  # out positionally: no keyword parsing
        elif simple == 3:
            pipe._clip(x, w)
        return w

    return apply


@dataclass(frozen=True)
class NoiseBlock:
    """One noise pipeline fused into one affine stage, as of its current block, for code that runs many pipelines
    at once (``sim2real.batched``): step ``t`` maps ``x`` to ``x * gain + offsets[row + t]`` (``gain`` None: 1.0),
    then :meth:`clip`; ``row == BLOCK``: spent, :meth:`SignalCorruptor.next_noise_block` draws the next block.
    ``offsets`` (``(BLOCK, size)``, read only) and ``gain`` are in the signal's dtype; ``low``/``high`` are the
    clip bounds (None: none); ``guard``: clip only entries whose clean value lies inside them (observations)."""

    offsets: np.ndarray
    gain: np.ndarray | None
    row: int
    low: np.ndarray | None
    high: np.ndarray | None
    guard: bool

    def clip(self, x: np.ndarray, w: np.ndarray) -> None:
        """Clips the noisy ``w`` in place as the pipeline does (``x``: the clean signal; any leading batch axes)."""
        if self.low is not None:
            if self.guard:
                np.copyto(w, _clip(w, self.low, self.high), where=(x >= self.low) & (x <= self.high))
            else:
                _clip(w, self.low, self.high, out=w)
