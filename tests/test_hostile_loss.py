"""Frames lost without a word, and files that change under the reader (issue 27).

Every frame of a valid file is replayed (two channels sharing ``/can/frames``, a UTF-8 BOM
before a text log); damage that costs frames is warned with what it cost (a BLF object
whose size field is absurd); a log that yields no frame at all is an error, not a
"replayed" row; an MCAP file that shrinks while it is replayed is "the file changed while
it was read", never SIGBUS; a live CSV whose file is deleted or replaced is a failure like
a full disk. Expected counts come from what each test wrote.
"""

from __future__ import annotations

import json
import os
import re
import struct
import subprocess
import sys
import threading
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from mcap.writer import CompressionType, Writer

from bench.cli import main
from bench.mcaplog import schemas as S
from bench.mcaplog.reader import McapLog
from tests.helpers import event_texts
from tests.test_hostile_paths import ROOT, guarded, one_error
from tests.test_mcap_hostile import frames_replayed, raw_frame

N = 3300


@pytest.fixture(scope="module")
def frames():
    from devices.emulator import scenario_from_dict, simulate

    f = simulate(scenario_from_dict({"duration_s": 5.0, "seed": 3, "sample_rate_hz": 200})).frames
    assert len(f) == N
    return f


def _replayed(capsys, path: Path, *extra: str) -> tuple[int, str, str]:
    """(exit code, the summary's frames count, stderr) of `bench replay PATH`."""
    code = main(["replay", str(path), "--csv", os.devnull, *extra])
    err = capsys.readouterr().err
    line = next((x for x in err.splitlines() if x.startswith("frames ")), "frames ?")
    return code, line.split()[-1], err


# -- channels sharing /can/frames ------------------------------------------------------------
def two_channel_file(path: Path, n: int = N) -> None:
    """``n`` frames alternating between two channels that are both /can/frames (the MCAP
    spec allows any number of channels per topic)."""
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=4096, compression=CompressionType.ZSTD)
        w.start(profile="", library="someone-else")
        sid = w.register_schema(S.FRAME_SCHEMA_NAME, "protobuf", S.FRAME_SCHEMA_DATA)
        cids = [w.register_channel(S.FRAME_TOPIC, "protobuf", sid) for _ in range(2)]
        for k in range(n):
            t = 1000.0 + k / 600
            payload = raw_frame(t, 0x101 + k % 3, k.to_bytes(8, "little"))
            w.add_message(cids[k % 2], int(t * 1e9), payload, int(t * 1e9))
        w.finish()


def test_every_channel_of_can_frames_is_replayed(tmp_path, capsys):
    """1 650 of 3 300 frames were replayed, and `bench log info` said 1 650."""
    from bench.mcaplog.source import McapFrameSource

    path = tmp_path / "two.mcap"
    two_channel_file(path)
    assert frames_replayed(path) == N
    src = McapFrameSource(path)
    got = [int.from_bytes(bytes(d), "little") for b in src.batches() for d in b.frames["data"]]
    src.close()
    assert got == list(range(N))  # in the order written, across both channels
    assert main(["log", "info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"] == N and info["topics"][S.FRAME_TOPIC] == N


def test_a_foreign_channel_on_can_frames_costs_no_frame_and_is_warned(tmp_path, capsys):
    """A JSON channel of another schema on /can/frames (the spec lets any channel use any
    topic) was read as 38-byte RawFrames: chunks skipped, 560 of 600 frames replayed."""
    n = 600
    path = tmp_path / "foreign.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=4096, compression=CompressionType.ZSTD)
        w.start(profile="", library="someone-else")
        sid = w.register_schema(S.FRAME_SCHEMA_NAME, "protobuf", S.FRAME_SCHEMA_DATA)
        other = w.register_schema("foxglove.Log", "jsonschema", b'{"type": "object"}')
        ours = w.register_channel(S.FRAME_TOPIC, "protobuf", sid)
        theirs = w.register_channel(S.FRAME_TOPIC, "json", other)
        for k in range(n):
            t = int((1000.0 + k / 600) * 1e9)
            w.add_message(ours, t, raw_frame(t / 1e9, 0x101 + k % 3, k.to_bytes(8, "little")), t)
            w.add_message(theirs, t, b'{"message": "someone else\'s"}', t)
        w.finish()
    code, got, err = _replayed(capsys, path)
    assert code == 0 and got == str(n), err
    note = f"channel {theirs} on /can/frames is not the bench's RawFrame (schema 'foxglove.Log'"
    assert note in err and f"its {n} messages are not frames" in err, err
    assert "parse_error" not in err, err
    assert main(["log", "info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"] == n
    assert info["topics"] == {S.FRAME_TOPIC: n, f"{S.FRAME_TOPIC} [foxglove.Log]": n}


# -- BLF with an absurd object size ----------------------------------------------------------
def test_blf_whose_first_object_size_is_absurd_loses_nothing_and_says_so(tmp_path, capsys, frames):
    """0xFFFFFFF0 in the first container's size: 2 730 of 3 300 frames, no warning."""
    from devices.writers import write_with_can_logger

    good = tmp_path / "good.blf"
    write_with_can_logger(good, frames)
    raw = bytearray(good.read_bytes())
    header_size = struct.unpack_from("<I", raw, 4)[0]
    assert raw[header_size : header_size + 4] == b"LOBJ"
    struct.pack_into("<I", raw, header_size + 8, 0xFFFFFFF0)
    bad = tmp_path / "bad.blf"
    bad.write_bytes(bytes(raw))
    code, n, err = _replayed(capsys, bad)
    assert code == 0 and n == str(N), err
    assert f"object at byte {header_size} claims {0xFFFFFFF0} bytes" in err


def test_blf_whose_second_container_is_damaged_says_what_the_header_declares(
    tmp_path, capsys, frames
):
    """Reading stopped at the damage with a count of what was replayed, not of the file."""
    from devices.writers import write_with_can_logger

    good = tmp_path / "good.blf"
    write_with_can_logger(good, frames)
    raw = bytearray(good.read_bytes())
    first = struct.unpack_from("<I", raw, 4)[0]  # the header's size: the first container
    second = first + struct.unpack_from("<I", raw, first + 8)[0]
    second += second % 4  # objects are padded to 4 bytes
    assert raw[second : second + 4] == b"LOBJ"
    raw[second + 132 : second + 182] = bytes(b ^ 0xFF for b in raw[second + 132 : second + 182])
    bad = tmp_path / "bad.blf"
    bad.write_bytes(bytes(raw))
    code, n, err = _replayed(capsys, bad)
    assert code == 0 and 0 < int(n) < N, err
    assert f"reading stopped after {n} frames" in err, err
    assert f"(its header declares {N} objects)" in err, err


# -- a UTF-8 byte-order mark -----------------------------------------------------------------
BOM = b"\xef\xbb\xbf"


@pytest.mark.parametrize("suffix", [".trc", ".asc", ".csv", ".log"])
def test_a_bom_before_a_text_log_loses_no_frame(tmp_path, capsys, frames, suffix):
    """.trc lost every frame (3 301 parse errors); .asc and candump their first line."""
    from devices.writers import write_candump, write_with_can_logger

    plain = tmp_path / f"plain{suffix}"
    if suffix == ".log":
        write_candump(plain, frames)
    else:
        write_with_can_logger(plain, frames)
    bom = tmp_path / f"bom{suffix}"
    bom.write_bytes(BOM + plain.read_bytes())
    code, n, err = _replayed(capsys, bom)
    assert code == 0 and n == str(N), err
    assert "warning" not in err and "parse_error" not in err, err


def test_a_bom_scenario_is_recorded_as_toml_reads_it(tmp_path):
    """An emulated MCAP kept the BOM in its ``scenario`` metadata: tomllib refuses that."""
    import tomllib

    sc = tmp_path / "s.toml"
    sc.write_bytes(BOM + b"duration_s = 1.0\nseed = 1\n")
    out = tmp_path / "o.mcap"
    assert main(["emulate", str(sc), "--out", str(out), "-q"]) == 0
    with McapLog(out) as lg:
        recorded = lg.metadata_dict()["scenario"]["toml"]
    assert tomllib.loads(recorded) == {"duration_s": 1.0, "seed": 1}


def test_a_bom_in_a_steps_file_and_a_tilt_table_is_read(tmp_path):
    from bench.acceptance.answers import load_answers
    from bench.calibration import read_table

    steps = tmp_path / "steps.toml"
    steps.write_bytes(BOM + b'[[answers]]\nanswer = "skip"\n')
    assert [a.answer for a in load_answers(steps)] == ["skip"]
    table = tmp_path / "table.csv"
    table.write_bytes(BOM + b"start_s,end_s,gradient_permil\n1,2,3.5\n")
    assert read_table(table).tolist() == [[1.0, 2.0, 3.5]]


def test_a_bom_in_a_scenario_and_a_plan_is_read(tmp_path, capsys):
    sc = tmp_path / "s.toml"
    sc.write_bytes(BOM + b"duration_s = 1.0\nseed = 1\n")
    assert main(["emulate", str(sc), "--out", str(tmp_path / "o.log"), "-q"]) == 0
    plan = tmp_path / "p.toml"
    plan.write_bytes(
        BOM + b'[plan]\ntitle = "bom"\nexpect = "pass"\n[scenario]\nduration_s = 1.0\n'
        b'[[checks]]\nkind = "no_frame_loss"\n'
    )
    assert main(["accept", str(plan), "--out", str(tmp_path / "acc"), "--no-plots"]) == 0


# -- a log without a single frame ---------------------------------------------------------
@pytest.fixture
def empty_logs(tmp_path: Path) -> dict[str, Path]:
    """Random bytes named .log, and an MCAP file cut before its first chunk."""
    noise = tmp_path / "noise.log"
    noise.write_bytes(os.urandom(4000))
    whole = tmp_path / "whole.mcap"
    two_channel_file(whole, 600)
    with McapLog(whole) as lg:
        first_chunk = lg.chunks[0].offset
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole.read_bytes()[: first_chunk + 20])  # inside the first chunk
    return {"noise": noise, "cut": cut}


@pytest.mark.parametrize("which", ["noise", "cut"])
def test_replay_of_a_log_without_frames_is_an_error(empty_logs, capsys, tmp_path, which):
    """It exited 0 with a header-only CSV."""
    path = empty_logs[which]
    out = tmp_path / "out.csv"
    line = one_error(main(["replay", str(path), "--csv", str(out)]), capsys.readouterr().err)
    assert path.name in line and "no frame" in line
    assert not out.exists()


@pytest.mark.parametrize("flag", ["--csv", "--parquet", "--candump"])
def test_log_export_of_an_mcap_without_frames_is_an_error(empty_logs, capsys, tmp_path, flag):
    """It exited 0 with a header-only CSV (a 0-byte candump log)."""
    out = tmp_path / "out.x"
    argv = ["log", "export", str(empty_logs["cut"]), flag, str(out)]
    line = one_error(main(argv), capsys.readouterr().err)
    assert "cut.mcap" in line and "no frame in this log" in line
    assert not out.exists()


def test_fleet_rows_of_logs_without_frames_are_errors(empty_logs, frames, tmp_path):
    """They counted as "replayed" with a null error, exit 0. And a FIFO among the logs
    waited forever; now it is that log's error row. Exit 1."""
    from devices.writers import write_candump

    good = tmp_path / "good.log"
    write_candump(good, frames)
    pipe = tmp_path / "pipe.log"
    os.mkfifo(pipe)
    logs = [good, empty_logs["noise"], empty_logs["cut"], pipe]
    out = tmp_path / "fleet"
    r = guarded(["fleet", *map(str, logs), "--out", str(out), "--workers", "2", "-q"], tmp_path)
    assert r.returncode == 1, r.stderr
    rows = {Path(row["path"]).name: row for row in pq.read_table(out / "logs.parquet").to_pylist()}
    assert rows["good.log"]["error"] is None and rows["good.log"]["frames"] == N
    assert "no frame" in rows["noise.log"]["error"] and "no frame" in rows["cut.mcap"]["error"]
    assert "FIFO" in rows["pipe.log"]["error"]
    assert re.search(r"\b3\s+failed", r.stderr), r.stderr
    parts = sorted(p.parent.name for p in (out / "results").glob("*/part-0.parquet"))
    assert parts == [f"log={rows['good.log']['log']}"]


# -- an MCAP file that shrinks while it is replayed --------------------------------------------
SHRINK = """
import os, sys
from bench.mcaplog import source
opened = source.McapFrameSource.__init__
def shrinking(self, path, **kw):
    opened(self, path, **kw)
    os.truncate(path, os.path.getsize(path) // 2)  # a copy still being written, cut
source.McapFrameSource.__init__ = shrinking
from bench.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_an_mcap_that_shrinks_while_replayed_is_an_error_not_sigbus(tmp_path):
    path = tmp_path / "shrinking.mcap"
    two_channel_file(path)
    out = tmp_path / "out.parquet"
    r = subprocess.run(
        [sys.executable, "-c", SHRINK, "replay", str(path), "--parquet", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2, (r.returncode, r.stderr)  # -7 was SIGBUS
    line = one_error(r.returncode, r.stderr)
    assert "changed while it was read" in line and "replay stopped after" in line
    assert not out.exists()


def test_mcap_reader_reports_a_shrunk_file_at_the_chunk_it_cannot_read(tmp_path):
    from bench.mcaplog.filebytes import FileChanged

    path = tmp_path / "shrinking.mcap"
    two_channel_file(path)
    with McapLog(path) as lg:
        chunks = lg.iter_chunks()
        next(chunks)  # the first chunk is read whole
        os.truncate(path, lg.chunks[1].offset)
        with pytest.raises(FileChanged, match="changed while it was read"):
            list(chunks)


@pytest.mark.parametrize("suffix", [".log", ".trc", ".bin"])
@pytest.mark.parametrize("change", ["shrinks", "grows"])
def test_a_device_log_that_changes_while_replayed_is_an_error(tmp_path, frames, suffix, change):
    """Read to its new end, the replay would pass another file's frames off as this one's."""
    from bench.errors import BenchError
    from devices.formats import open_log
    from devices.writers import write_candump, write_uart_bin, write_with_can_logger

    path = tmp_path / f"changing{suffix}"
    {".log": write_candump, ".bin": write_uart_bin}.get(suffix, write_with_can_logger)(path, frames)
    size = path.stat().st_size
    src = open_log(path, chunk_bytes=4096)
    batches = src.batches(max_frames=100)
    next(batches)  # reading has begun
    if change == "shrinks":
        os.truncate(path, size // 2)
    else:
        with path.open("ab") as f:
            f.write(path.read_bytes()[: size // 4])
    with pytest.raises(BenchError, match="changed while it was read"):
        list(batches)
    src.close()


# -- a live CSV whose file goes away -----------------------------------------------------------
LIVE = 'description = "live csv"\nduration_s = 2.5\nseed = 4\nsample_rate_hz = 200\n'


@pytest.mark.parametrize("how", ["folder", "deleted", "symlink"])
def test_a_live_csv_that_disappears_is_a_failure(tmp_path, capsys, how):
    """Deleted and replaced by a folder or a symlink mid-run: exit 0, every row gone."""
    sc = tmp_path / "live.toml"
    sc.write_text(LIVE)
    out, log = tmp_path / "live.csv", tmp_path / "run.mcap"
    done = threading.Event()

    def hostile() -> None:  # as soon as the CSV is being written, take it away
        while not done.wait(0.02):
            partial = [p for p in tmp_path.iterdir() if p.name.startswith(".live.partial")]
            if partial:
                if how == "folder":
                    out.mkdir()
                else:
                    partial[0].unlink()
                    if how == "symlink":
                        partial[0].symlink_to(tmp_path / "elsewhere.csv")
                return

    thread = threading.Thread(target=hostile, daemon=True)
    thread.start()
    try:
        code = main(["run", "--emulate", str(sc), "--csv", str(out), "--mcap", str(log)])
    finally:
        done.set()
        thread.join(5)
    err = capsys.readouterr().err
    assert code == 1, err
    assert f"bench: error: {out}: cannot write the CSV: " in err, err
    assert "during the run" in err and "Traceback" not in err, err
    assert not out.is_file()
    events = event_texts(log)
    assert any(e.startswith("OUTPUT_ERROR") for e in events), events
    assert f"bench: log written: {log}" in err, err  # the MCAP went on
