"""MCAP logging of bench runs: every raw frame and every derived result, replayable.

Writer side: :class:`~bench.mcaplog.writer.McapSink` (live runs) and
:func:`~bench.mcaplog.writer.write_emulation` (emulator output). Reader side:
:mod:`bench.mcaplog.reader` (fast frame reader, recorded results/events/metadata),
:mod:`bench.mcaplog.info` and :mod:`bench.mcaplog.compare`. The file layout is
specified in docs/MCAP.md.
"""

from __future__ import annotations
