"""The estimator's kernel made ready before the first sample needs it, and a word meanwhile.

numba compiles the estimator's kernel on the first start after an install or an update
(about 20 s on a quiet 2-core machine, 40 s on a busy one) and caches it on disk; later
starts load it in about a second. Nothing else needs it, so nobody has to stare at a blank
terminal: a live screen runs a preview pipeline (the reference method, the estimator's
columns pending) while a thread prepares the kernel, and then the full pipeline catches up
on every frame held meanwhile (:class:`bench.live.runner.LiveRunner`); the headless
commands say one line on stderr and wait (:func:`prepare`), a replay while its first
stage decodes and fuses the log's first frames (:func:`bench.replay.run.replay`).

The estimator is reached through two functions only, ``kernel_is_ready`` and ``warm_up``
of :mod:`bench.fusion.estimator`, imported when called: the TUI's screen process imports
this module for :class:`WarmUpStatus` and must not import fusion.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bench.records.events import EVENT_DTYPE

NOTICE = (
    "preparing the estimator (first start: compiling its kernel, about 20-40 s; "
    "cached for later starts) ..."
)
"""What a headless command says before the first compile."""

SPINNER = "⠋⠙⠹⠸⠼⠴⠦⠧⠇⠏"


@dataclass(frozen=True, slots=True)
class WarmUpStatus:
    """How far the estimator's preparation got, for a screen."""

    elapsed_s: float
    held_frames: int  # frames received meanwhile, waiting for the full pipeline
    dropped_frames: int = 0  # received beyond the hold's bound: never logged (counted)
    error: str | None = None

    def spinner(self) -> str:
        return SPINNER[int(self.elapsed_s * 4) % len(SPINNER)]

    def headline(self) -> str:
        return f"{self.spinner()} preparing the estimator · {self.elapsed_s:.0f} s"

    def detail(self) -> str:
        if self.error:
            return f"it failed: {self.error}"
        return "numba compiles its kernel (first start; cached for later ones)"


def kernel_is_ready() -> bool:
    """The kernel is in this process or in numba's disk cache: no compile needed."""
    from bench.fusion.estimator import kernel_is_ready as ready

    return ready()


def prepare(say: Callable[[str], None]) -> float | None:
    """For a headless command: if the kernel needs compiling, say so in one line, compile
    it and say how long it took (returned, s); None when it was ready."""
    if kernel_is_ready():
        return None
    from bench.fusion.estimator import warm_up

    say(NOTICE)
    started = time.monotonic()
    warm_up()
    took = time.monotonic() - started
    say(f"estimator ready ({took:.0f} s)")
    return took


class KernelWarmUp:
    """Prepares the kernel in a thread of its own; :attr:`ready` once it is there."""

    def __init__(
        self,
        work: Callable[[], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._work = work
        self._clock = clock
        self._done = threading.Event()
        self.started = clock()
        self.took_s: float | None = None
        self.error: str | None = None

    @classmethod
    def if_needed(cls) -> KernelWarmUp | None:
        """A started warm-up, or None when the kernel is ready already."""
        return None if kernel_is_ready() else cls().start()

    def start(self) -> KernelWarmUp:
        threading.Thread(target=self._run, name="estimator-warm-up", daemon=True).start()
        return self

    def _run(self) -> None:
        try:
            if self._work is not None:
                self._work()
            else:
                from bench.fusion.estimator import warm_up

                warm_up()
        except Exception as exc:  # the run says so; its pipeline cannot be built
            self.error = f"{type(exc).__name__}: {exc}"
        finally:
            self.took_s = self._clock() - self.started
            self._done.set()

    @property
    def ready(self) -> bool:
        """Done (check :attr:`error`)."""
        return self._done.is_set()

    def wait(self, timeout: float | None = None) -> bool:
        return self._done.wait(timeout)

    def status(self, held_frames: int = 0, dropped_frames: int = 0) -> WarmUpStatus:
        return WarmUpStatus(self._clock() - self.started, held_frames, dropped_frames, self.error)


class PendingEstimator:
    """Stands in for the estimator in the preview pipeline: every estimate pending (NaN,
    nothing excluded), no events. Same interface as :class:`bench.fusion.estimator.Estimator`
    as the pipeline calls it."""

    def __init__(self) -> None:
        from bench.records.results import ESTIMATE_DTYPE

        self._row = np.zeros(1, dtype=ESTIMATE_DTYPE)
        for name in ESTIMATE_DTYPE.names or ():
            if ESTIMATE_DTYPE[name].kind == "f":
                self._row[name] = np.nan
        self._tuple = tuple(self._row[0].tolist())
        self._no_events = np.zeros(0, dtype=EVENT_DTYPE)

    def push(
        self, samples: np.ndarray, acc: np.ndarray, usable: np.ndarray, speeds: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        return np.repeat(self._row, len(samples)), self._no_events
