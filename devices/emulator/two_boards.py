"""Two boards on one bus sharing one odometer (ICD 1: each board at its own BASE; SPEED_REF
0x180 comes from the train's one odometer).

A scenario with ``[second_board]`` runs the train once and puts two boards on it: the
first is the scenario's own board (its sensors, faults, SPEED_REF); the second has its own
BASE, sensors, board and random draws (noise, body vibration and modes, the load at
stations), sits ``offset_m`` ahead along the train (so it meets the track's grade changes,
vertical curves and joints that much earlier) and sends no SPEED_REF. Both boards' frames
then share one bus: they are merged by send time (at equal times the lower BASE wins
arbitration; each board's own order, its faults' reordering included, is kept) and
re-serialised, a frame waiting for the one before it to be done (each its own board's
``frame_gap_us``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from devices.emulator.scenario import Scenario
from devices.emulator.simulation import Simulation, UartStream, simulate

SEED_MOD = 1 << 63


def board_b(sc: Scenario) -> Scenario:
    """The second board's own scenario: the same train, line and body physics; its BASE,
    sensors, board and seed; ``offset_m`` ahead; no SPEED_REF and none of the first board's
    faults."""
    b = sc.second_board
    if b is None:
        raise ValueError(f"{sc.source}: no [second_board]")
    return replace(
        sc,
        seed=b.seed if b.seed is not None else (sc.seed + 1) % SEED_MOD,
        base_id=b.base_id,
        sample_rate_hz=b.sample_rate_hz,
        channels=b.channels,
        board=b.board,
        counter0=b.counter0,
        board_time0_ticks=b.board_time0_ticks,
        initial_position_m=sc.initial_position_m + b.offset_m,
        speed_ref=False,
        faults=(),
        second_board=None,
        source=f"{sc.source} [second_board]",
    )


def one_bus(a: Simulation, b: Simulation) -> np.ndarray:
    """Both boards' frames on one bus, in send order, re-serialised."""
    frames = np.concatenate([a.frames, b.frames])
    us = np.rint(frames["t"] * 1e6).astype(np.int64)
    # each board's order is kept: merge on its running-maximum time, the lower BASE first
    key = np.concatenate(
        [np.maximum.accumulate(us[: len(a.frames)]), np.maximum.accumulate(us[len(a.frames) :])]
    )
    first_wins = a.scenario.base_id < b.scenario.base_id
    rank = np.concatenate(
        [
            np.full(len(a.frames), 0 if first_wins else 1),
            np.full(len(b.frames), 1 if first_wins else 0),
        ]
    )
    gap = np.concatenate(
        [
            np.full(len(a.frames), a.scenario.board.frame_gap_us, dtype=np.int64),
            np.full(len(b.frames), b.scenario.board.frame_gap_us, dtype=np.int64),
        ]
    )
    order = np.lexsort((rank, key))
    frames, us, gap = frames[order], us[order], gap[order]
    # send[k] = max(us[k], send[k-1] + gap[k-1]): minus the bus time before k, a running max
    before = np.concatenate([[0], np.cumsum(gap[:-1])]) if len(gap) else gap
    frames["t"] = (np.maximum.accumulate(us - before) + before) / 1e6
    return frames


@dataclass(eq=False)
class BusRun:
    """Two boards' run on one bus: ``frames`` as a receiver sees them; each board's own
    :class:`Simulation` (truth, faults' effects) in ``boards``. ``truth`` and ``t0`` are
    the first board's (the train's truth; the second board's is ``boards[1].truth``)."""

    boards: tuple[Simulation, Simulation]
    frames: np.ndarray

    @property
    def scenario(self) -> Scenario:
        return self.boards[0].scenario

    @property
    def truth(self) -> np.ndarray:
        return self.boards[0].truth

    @property
    def t0(self) -> float:
        return self.boards[0].t0

    def uart_stream(self) -> UartStream:
        """The UART is one board's own link: the first board's."""
        return self.boards[0].uart_stream()

    def summary(self) -> str:
        a, b = self.boards
        return "\n".join(
            (
                f"one bus: {len(self.frames)} frames of two boards "
                f"(BASE 0x{a.base_id:X} with SPEED_REF, 0x{b.base_id:X} without)",
                a.summary(),
                b.summary(),
            )
        )


def simulate_bus(sc: Scenario) -> BusRun:
    """Run a scenario with ``[second_board]``: both boards on one train, one bus."""
    a = simulate(replace(sc, second_board=None))
    b = simulate(board_b(sc))
    return BusRun((a, b), one_bus(a, b))


__all__ = ["BusRun", "board_b", "one_bus", "simulate_bus"]
