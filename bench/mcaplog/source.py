"""Replay source for the bench's own MCAP logs (``bench replay FILE.mcap``).

Yields the recorded raw frames in their original arrival order, with the recorded UART
link errors and source notices, so the pipeline recomputes exactly what the live run
computed. A truncated or unfinished file yields every complete chunk and then a
``truncated`` notice saying how much was lost; it never raises for a damaged tail.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

from bench.errors import BenchError
from bench.mcaplog import schemas as S
from bench.mcaplog.filebytes import FileChanged
from bench.mcaplog.reader import McapLog
from devices.base import FileSource, SourceBatch, SourceNotice
from devices.bus import one_line


def open_mcap(path: Path, **kwargs: object) -> McapFrameSource:
    """The opener :func:`devices.formats.open_log` calls for ``.mcap``: any failure of
    the reader on a damaged file is one BenchError line."""
    try:
        return McapFrameSource(path, **kwargs)  # type: ignore[arg-type]  # batching: str
    except BenchError:
        raise
    except Exception as exc:
        raise BenchError(f"cannot read {path}: {one_line(exc)}") from exc


class McapFrameSource(FileSource):
    """Frames of a bench MCAP file as SourceBatches (see bench.mcaplog.reader)."""

    def __init__(self, path: str | Path, *, batching: str = "merge", **_options: object) -> None:
        """``batching``: "merge" (default, fast: chunks merged into large batches; the
        pipeline's output does not depend on batching) or "recorded" (the live run's own
        batches, for forensic exactness). Other options are meant for other file kinds
        (devices.formats.open_log passes them all) and do not apply here."""
        if batching not in ("merge", "recorded"):
            raise ValueError(f"batching must be 'merge' or 'recorded', not {batching!r}")
        self.batching = batching
        self.path = Path(path)
        self.log = McapLog(self.path)
        if foreign := self.log.foreign_topics():
            self.log.close()
            raise BenchError(
                f"{self.path}: no bench topics in this MCAP file (a replay reads "
                f"{S.FRAME_TOPIC}; it holds {', '.join(foreign[:6])})"
            )
        run = self.log.metadata_dict().get("run", {})
        recorded = run.get("source", "")
        self.description = f"MCAP log {self.path.name}" + (
            f" (recorded from {recorded})" if recorded else ""
        )
        self._position = 0

    def batches(self, max_frames: int = 65536) -> Iterator[SourceBatch]:
        frames = 0
        try:
            for batch in self._batches(max_frames):
                frames += len(batch.frames)
                yield batch
        except FileChanged as exc:  # what was replayed, then the error: never a signal
            raise FileChanged(
                f"{exc} (replay stopped after {frames} frames, at byte {self._position})"
            ) from None

    def _batches(self, max_frames: int) -> Iterator[SourceBatch]:
        last_t = math.nan
        bad_seen = len(self.log.bad_chunks)
        recorded = self.batching == "recorded"
        for batch, reached in self.log.iter_batches(max_frames, recorded=recorded):
            self._position = reached
            if len(batch.frames):
                last_t = float(batch.frames["t"][-1])
            for info, why in self.log.bad_chunks[bad_seen:]:
                batch.notices.append(
                    SourceNotice(
                        last_t,
                        "parse_error",
                        f"{self.path.name}: chunk at byte {info.offset} skipped ({why})",
                    )
                )
            bad_seen = len(self.log.bad_chunks)
            yield batch
        notices = [
            SourceNotice(
                last_t,
                "parse_error",
                f"{self.path.name}: chunk at byte {info.offset} skipped ({why})",
            )
            for info, why in self.log.bad_chunks[bad_seen:]
        ]
        notices += [SourceNotice(last_t, "parse_error", d) for d in self.log.damage]
        notices += [SourceNotice(last_t, "info", d) for d in self.log.foreign_notes]
        if self.log.truncated:
            notices.append(SourceNotice(last_t, "truncated", self.log.truncation))
        self._position = self.log.size
        if notices:
            yield SourceBatch(notices=notices)

    def size_bytes(self) -> int:
        return self.log.size

    def frame_count(self) -> int:
        """The frames the file holds (its message index: no decompression), for a replay's
        progress."""
        return int(self.log.message_counts().get(S.FRAME_TOPIC, 0))

    def position(self) -> int:
        return self._position

    def close(self) -> None:
        self.log.close()
