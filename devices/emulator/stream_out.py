"""``bench emulate --out FILE [--truth CSV]`` in bounded memory: the run's chunks
(:func:`devices.emulator.stream.simulate_chunks`) go to the files as they are computed.

The files are byte for byte what the whole ``simulate()`` gives (``write_candump`` of its
frames, its ``uart_bytes()``, :func:`devices.emulator.player.write_truth_csv`: the candump
writer streams; the UART bytes and the truth rows of consecutive chunks follow one
another), and the summary is :meth:`Simulation.summary`'s text.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from typing import IO, Any

import numpy as np

from devices.emulator.engine import TRUTH_COLUMNS
from devices.emulator.scenario import Scenario
from devices.emulator.stream import CHUNK_S, Chunk, RunCounts, simulate_chunks
from devices.errors import BenchError
from devices.paths import staged

OUT_SUFFIXES = (".log", ".bin", ".mcap")

McapStreamWriter = Callable[[Path, Iterator[Chunk], Scenario], dict[str, int]]
"""The bench's MCAP writer for chunks (devices/ never imports bench/)."""


def write_truth_rows(f: IO[bytes], truth: np.ndarray, header: bool) -> None:
    """Truth rows of the CSV (time_s, counter, then the physical columns; the header line
    only when asked): ``bench emulate --truth`` and write_truth_csv both write them."""
    np.savetxt(
        f,
        np.column_stack([truth[c] for c in TRUTH_COLUMNS]),
        fmt=["%.6f", "%d"] + ["%.12g"] * (len(TRUTH_COLUMNS) - 2),
        delimiter=",",
        header=",".join(TRUTH_COLUMNS) if header else "",
        comments="",
    )


def write_streamed(
    sc: Scenario,
    out: str | Path | None,
    truth: str | Path | None = None,
    *,
    mcap_writer: McapStreamWriter | None = None,
    chunk_s: float = CHUNK_S,
) -> tuple[list[str], RunCounts]:
    """Run ``sc`` chunk by chunk into ``out`` (.log/.bin/.mcap) and/or the ``truth`` CSV.
    Returns the lines to print (as the whole-run writers word them) and the run's counts."""
    p = Path(out) if out is not None else None
    suffix = p.suffix.lower() if p is not None else ""
    if p is not None and suffix not in OUT_SUFFIXES:
        raise BenchError(
            f"{p}: unknown output type {suffix or '(none)'!r} (expected .log, .bin or .mcap)"
        )
    if suffix == ".mcap" and mcap_writer is None:
        raise BenchError(
            "mcap output needs the bench's MCAP writer (bench emulate passes it); "
            "write .log or .bin instead"
        )
    counts = RunCounts(sc)
    truth_rows = [0]
    try:
        line = _write(sc, p, suffix, truth, mcap_writer, chunk_s, counts, truth_rows)
    except OSError as exc:  # renaming a finished file into place
        raise BenchError(f"{exc.filename or p}: cannot write: {exc.strerror or exc}") from None
    lines = []
    if truth is not None:
        lines.append(f"wrote truth of {truth_rows[0]} sampling instants to {truth}")
    if line is not None:
        lines.append(line)
    return lines, counts


def _write(
    sc: Scenario,
    p: Path | None,
    suffix: str,
    truth: str | Path | None,
    mcap_writer: McapStreamWriter | None,
    chunk_s: float,
    counts: RunCounts,
    truth_rows: list[int],
) -> str | None:
    """The files written under temporary names, renamed into place once all are complete
    (a run that fails part way leaves neither, and keeps what the names held)."""
    with contextlib.ExitStack() as stack:
        truth_file = None
        if truth is not None:
            truth_file = _open(stack, stack.enter_context(staged(truth)), truth)
        out = stack.enter_context(staged(p)) if p is not None else None

        def chunks() -> Iterator[Chunk]:
            first = True
            for chunk in simulate_chunks(sc, uart=suffix == ".bin", chunk_s=chunk_s, counts=counts):
                if truth_file is not None:
                    _guarded(truth, partial(write_truth_rows, truth_file, chunk.truth, first))
                    truth_rows[0] += len(chunk.truth)
                first = False
                yield chunk

        if p is None or out is None:
            for _ in chunks():
                pass
            return None
        if suffix == ".log":
            return _write_candump(out, chunks(), counts, p)
        if suffix == ".bin":
            f = _open(stack, out, p)
            for chunk in chunks():
                _guarded(p, partial(f.write, chunk.uart))
            return (
                f"wrote {counts.packets} UART packets ({counts.uart_bytes} bytes, "
                f"{counts.packets_broken} broken by UART faults) to {p}"
            )
        assert mcap_writer is not None
        written = mcap_writer(out, chunks(), sc)
        return f"wrote {written.get('frames', counts.frames)} CAN frames and truth to {p}"


def _write_candump(out: Path, chunks: Iterator[Chunk], counts: RunCounts, p: Path) -> str:
    from devices.writers import CandumpWriter

    try:
        with CandumpWriter(out) as writer:
            for chunk in chunks:
                writer.write(chunk.frames)
    except BenchError as exc:  # named after the file the operator asked for
        raise BenchError(str(exc).replace(str(out), str(p))) from None
    return f"wrote {counts.frames} CAN frames to {p}"


def _open(stack: contextlib.ExitStack, path: str | Path, shown: str | Path) -> IO[bytes]:
    try:
        return stack.enter_context(Path(path).open("wb"))
    except OSError as exc:
        raise BenchError(f"{shown}: cannot write: {exc.strerror or exc}") from None


def _guarded(path: Any, write: Callable[[], Any]) -> None:
    try:
        write()
    except OSError as exc:
        raise BenchError(f"{path}: cannot write: {exc.strerror or exc}") from None


__all__ = ["OUT_SUFFIXES", "write_streamed", "write_truth_rows"]
