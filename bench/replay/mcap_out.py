"""`bench replay --mcap OUT`: the replay's frames, samples, results and events as an MCAP log,
the results' messages with the smoother's columns under `--smooth` (their schema says so).

The file is written under a temporary name beside OUT and renamed into place when whole,
like the replay's CSV and Parquet outputs: a failed replay leaves none. The writer is the
live runs' McapSink; its queue (10 000 steps of up to 65 536 frames) is never full in a
replay, and a step it had to drop would be an error, not a silent gap.
"""

from __future__ import annotations

from pathlib import Path

from bench.config import Config
from bench.errors import BenchError
from bench.sinks.tables import TableSink
from devices.paths import StagedFile


class ReplayMcap:
    """The MCAP log of one replay (see the module's docstring)."""

    def __init__(self, target: str, config: Config, source: str, smoothed: bool) -> None:
        from bench.mcaplog.file import check_writable
        from bench.mcaplog.sink import McapSink

        if problem := check_writable(Path(target)):
            raise BenchError(f"cannot write the MCAP log {target}: {problem}")
        self.staged = StagedFile(target)
        try:
            path = self.staged.create()
        except OSError as exc:
            raise BenchError(f"cannot write the MCAP log {target}: {exc.strerror or exc}") from None
        columns = None
        if smoothed:
            from bench.replay.model_columns import mcap_columns

            columns = mcap_columns()
        meta = {"source": source, "command": "bench replay", "smoothed": str(smoothed).lower()}
        attachments = []
        if config.path is not None and Path(config.path).is_file():
            attachments.append((Path(config.path).name, Path(config.path).read_bytes()))
        self.sink = McapSink(path, config, meta, attachments, result_columns=columns)

    def finish(self) -> None:
        """Close the log; a write failure or a dropped step is a one-line error, the file
        removed."""
        self.sink.close()
        why = self.sink.error or (
            f"{self.sink.dropped} frames dropped by its writer" if self.sink.dropped else ""
        )
        if why:
            self.staged.discard()
            raise BenchError(f"{self.staged.path}: cannot write the MCAP log: {why}")

    def commit(self) -> None:
        """Rename the finished log into place."""
        try:
            self.staged.commit()
        except OSError as exc:
            raise BenchError(f"{exc.filename}: cannot write the MCAP log: {exc.strerror}") from None

    def abort(self) -> None:
        """Close and remove the log after another failure."""
        try:
            self.sink.close()
        finally:
            self.staged.discard()


def close_outputs(tables: list[TableSink], mcap: ReplayMcap | None) -> None:
    """Finish the MCAP log, then the tables (bench.sinks.tables.close_all), then rename the
    log into place: the one that fails takes the others with it (whole or absent)."""
    from bench.sinks.tables import abort_all, close_all

    if mcap is not None:
        try:
            mcap.finish()
        except BaseException:
            abort_all(tables)
            raise
    try:
        close_all(tables)
    except BaseException:
        if mcap is not None:
            mcap.staged.discard()
        raise
    if mcap is not None:
        mcap.commit()
