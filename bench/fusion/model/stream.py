"""The model's forward pass as a stream, and a fixed-lag smoother on top (issue 26, live).

:class:`ForwardStream` takes what the estimator's filter is given, push by push, as
:class:`~bench.fusion.model.log.ModelLog` does, and runs the forward pass
(:func:`bench.fusion.model.run.forward`, the one kernel) over every block the pushes have
completed. What it carries between pushes is everything the kernel would have held in its
loop: x and P, the body's vibration learnt, the jump test's onset hypotheses, the last
block's mid-time, the samples of the block not yet complete and the SPEED_REF frames they
are still to apply. So its blocks are the replay's blocks to the bit, whatever the cut
(tests/test_model_stream.py).

:class:`FixedLag` keeps the last ``lag`` blocks' predicted and filtered (x, P) and, as each
block arrives, smooths back over them (the RTS pass of :mod:`.smoother`): block k's
estimate given everything up to block k + lag. It too depends on blocks only, never on
the cut.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.config import Config
from bench.fusion.model import jump, run, smoother, state
from bench.fusion.model.log import (
    BLOCK_S,
    CHANNEL_GATE,
    ODOMETER_GATE,
    channel_inputs,
    gradient_permil,
    params,
)

Frames = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""SPEED_REF frames as the filter gets them: anchor index, board time, speed, restart,
standstill."""


@dataclass(frozen=True, slots=True)
class Blocks:
    """Per block completed: mid-time s, predicted and filtered x (k, NX) and P (k, NX, NX),
    the Jacobian into each block from the one before."""

    t: np.ndarray
    x_pred: np.ndarray
    p_pred: np.ndarray
    x_filt: np.ndarray
    p_filt: np.ndarray
    jac: np.ndarray

    def __len__(self) -> int:
        return len(self.t)


def no_blocks() -> Blocks:
    nx = state.NX
    return Blocks(
        np.zeros(0),
        np.zeros((0, nx)),
        np.zeros((0, nx, nx)),
        np.zeros((0, nx)),
        np.zeros((0, nx, nx)),
        np.zeros((0, nx, nx)),
    )


def _no_frames() -> Frames:
    return (
        np.zeros(0, np.int64),
        np.zeros(0),
        np.zeros(0),
        np.zeros(0, np.bool_),
        np.zeros(0, np.bool_),
    )


class ForwardStream:
    """The forward pass over pushes (see the module docstring)."""

    def __init__(self, config: Config, **override: float) -> None:
        prm = params(config, **override)
        self.prm = prm.array()
        self.g = config.g
        th = np.asarray(config.angles_rad, dtype=np.float64)
        self._cos, self._sin = np.cos(th), np.sin(th)
        self.block = max(1, int(BLOCK_S * config.sample_rate_hz))
        self.x, self.p = state.initial(prm)
        self._vib = np.zeros(2)
        self._glr = jump.hypotheses(prm, BLOCK_S)
        self._t_prev = 0.0
        self._first = True
        self.blocks = 0  # blocks completed so far
        self.samples = 0  # samples pushed so far
        self._b = np.zeros(0)  # the samples of the block not yet complete
        self._y = np.zeros((0, 3))
        self._used = np.zeros((0, 3), np.bool_)
        self._frames = _no_frames()  # frames still to apply, anchored into self._b

    def push(
        self, b: np.ndarray, acc: np.ndarray, mask: np.ndarray, frames: Frames | None
    ) -> Blocks:
        """One push (as :meth:`ModelLog.add <bench.fusion.model.log.ModelLog.add>` takes it);
        returns the blocks it completed."""
        y, used = channel_inputs(acc, mask)
        held = len(self._b)
        self.samples += len(y)
        self._b = np.concatenate([self._b, np.asarray(b, dtype=np.float64)])
        self._y = np.concatenate([self._y, y])
        self._used = np.concatenate([self._used, used])
        if frames is not None and len(frames[0]):
            fa = np.asarray(frames[0], dtype=np.int64) + held
            new = (fa, *(np.asarray(c) for c in frames[1:]))
            self._frames = tuple(  # type: ignore[assignment]  # five arrays as ever
                np.concatenate([old, c.astype(old.dtype)])
                for old, c in zip(self._frames, new, strict=True)
            )
        return self._run((len(self._b) // self.block) * self.block)

    def finish(self) -> Blocks:
        """The end of the stream: the last block, however few samples it has."""
        return self._run(len(self._b))

    def _run(self, upto: int) -> Blocks:
        """The forward pass over the first ``upto`` samples held (whole blocks, or the
        stream's end), with the frames it applies: those before the first anchored at or
        beyond ``upto`` (the kernel applies frames in order, each once its block is in)."""
        if upto == 0:
            return no_blocks()
        fa = self._frames[0]
        beyond = np.flatnonzero(fa >= upto)
        nf = int(beyond[0]) if len(beyond) else len(fa)
        take = tuple(c[:nf] for c in self._frames)
        t_mid, xp, pp, xf, pf, jac, _, _ = run.forward(
            self._b[:upto], self._y[:upto], self._used[:upto],
            take[0], take[1].astype(np.float64), take[2].astype(np.float64),
            take[3].astype(np.bool_), take[4].astype(np.bool_), np.ones(nf, np.bool_),
            self._cos, self._sin, self.prm, self.x, self.p, self.block,
            ODOMETER_GATE, CHANNEL_GATE, self._vib, self._glr, self._t_prev, self._first,
        )  # fmt: skip
        self._first = False
        self.x, self.p, self._t_prev = xf[-1], pf[-1], float(t_mid[-1])
        self.blocks += len(t_mid)
        self._b, self._y, self._used = self._b[upto:], self._y[upto:], self._used[upto:]
        rest = tuple(c[nf:] for c in self._frames)
        self._frames = (rest[0] - upto, *rest[1:])  # type: ignore[assignment]
        return Blocks(t_mid, xp, pp, xf, pf, jac)


@dataclass(frozen=True, slots=True)
class Lagged:
    """Blocks smoothed with ``lag`` blocks after each: mid-time s, x (k, NX), 1-sigma
    (k, NX), and the gradient and its 1-sigma, permil."""

    t: np.ndarray
    x: np.ndarray
    sigma: np.ndarray
    gradient: np.ndarray
    gradient_sigma: np.ndarray

    def __len__(self) -> int:
        return len(self.t)


class FixedLag:
    """RTS over the last ``lag`` blocks as each block arrives (module docstring)."""

    def __init__(self, lag: int, g: float) -> None:
        self.lag = max(0, int(lag))
        self.g = g
        nx = state.NX
        self._cap = 2 * (self.lag + 1) + 64
        self._t = np.zeros(self._cap)
        self._xp = np.zeros((self._cap, nx))
        self._pp = np.zeros((self._cap, nx, nx))
        self._xf = np.zeros((self._cap, nx))
        self._pf = np.zeros((self._cap, nx, nx))
        self._jac = np.zeros((self._cap, nx, nx))
        self._lo = 0  # the oldest block kept (not yet given out)
        self._hi = 0  # one past the newest

    def push(self, blocks: Blocks) -> Lagged:
        """Take the new blocks; give out each block that now has ``lag`` blocks after it."""
        out: list[tuple[float, np.ndarray, np.ndarray]] = []
        for i in range(len(blocks)):
            self._append(blocks, i)
            if self._hi - self._lo > self.lag:
                xs, ps = self._smooth()
                out.append((float(self._t[self._lo]), xs[0], ps[0]))
                self._lo += 1
        return self._lagged(out)

    def finish(self) -> Lagged:
        """The stream ended: every block still kept, smoothed given all there is."""
        if self._hi == self._lo:
            return self._lagged([])
        xs, ps = self._smooth()
        out = [(float(self._t[self._lo + i]), xs[i], ps[i]) for i in range(len(xs))]
        self._lo = self._hi
        return self._lagged(out)

    def _append(self, blocks: Blocks, i: int) -> None:
        if self._hi == self._cap:  # keep the window contiguous: move it to the front
            k = self._hi - self._lo
            for a in (self._t, self._xp, self._pp, self._xf, self._pf, self._jac):
                a[:k] = a[self._lo : self._hi]
            self._lo, self._hi = 0, k
        j = self._hi
        self._t[j] = blocks.t[i]
        self._xp[j], self._pp[j] = blocks.x_pred[i], blocks.p_pred[i]
        self._xf[j], self._pf[j] = blocks.x_filt[i], blocks.p_filt[i]
        self._jac[j] = blocks.jac[i]
        self._hi += 1

    def _smooth(self) -> tuple[np.ndarray, np.ndarray]:
        w = slice(self._lo, self._hi)
        return smoother.rts(self._xp[w], self._pp[w], self._xf[w], self._pf[w], self._jac[w])

    def _lagged(self, out: list[tuple[float, np.ndarray, np.ndarray]]) -> Lagged:
        nx = state.NX
        t = np.array([o[0] for o in out], dtype=np.float64)
        x = np.array([o[1] for o in out], dtype=np.float64).reshape(len(out), nx)
        p = np.array([o[2] for o in out], dtype=np.float64).reshape(len(out), nx, nx)
        var = np.diagonal(p, axis1=1, axis2=2)
        grad, gsig = gradient_permil(x[:, state.S], var[:, state.S], self.g)
        return Lagged(t, x, np.sqrt(np.maximum(var, 0.0)), grad, gsig)
