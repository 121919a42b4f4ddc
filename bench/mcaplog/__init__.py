"""MCAP logging of bench runs: every raw frame and every derived result, replayable.

Writing: :mod:`~bench.mcaplog.file` (the chunked file writer), :mod:`~bench.mcaplog.encoder`
(the topics as messages), :mod:`~bench.mcaplog.sink` (``McapSink``, live runs; in a process
of its own through :mod:`~bench.mcaplog.writer_process`) and :mod:`~bench.mcaplog.emulation`
(emulator output). Reading: :mod:`bench.mcaplog.reader` (``McapLog``, the fast frame
reader, over :mod:`~bench.mcaplog.structure` and :mod:`~bench.mcaplog.decoders`),
:mod:`bench.mcaplog.recorded` (recorded results/events/metadata as rows),
:mod:`bench.mcaplog.source` (a log as a replay source),
:mod:`bench.mcaplog.info` and :mod:`bench.mcaplog.compare`. :mod:`bench.mcaplog.schemas`
holds the topics and their encodings; the file layout is specified in docs/MCAP.md.
"""
