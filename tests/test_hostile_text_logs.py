"""python-can text logs (.asc .trc .csv) with damaged lines: every frame line is either a
frame or a counted parse error, and reading goes on past a line python-can raises on
(issue 16 item 11).

The logs are written by python-can's own writers from 100 known frames, then damaged here;
the expectations are counts of the lines damaged (frames read + parse errors = 100).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.cli import main
from devices.formats import open_log
from devices.writers import write_with_can_logger
from protocol.frames import FRAME_DTYPE

N = 100


def frames(n: int = N) -> np.ndarray:
    f = np.zeros(n, dtype=FRAME_DTYPE)
    f["t"] = (1_700_000_000_000_000 + np.arange(n) * 1667) / 1e6
    f["id"] = 0x101 + np.arange(n) % 3
    f["dlc"] = 8
    f["data"] = np.random.default_rng(3).integers(0, 256, (n, 8))
    return f


def written(tmp: Path, suffix: str) -> tuple[list[str], list[int]]:
    """A good log's lines and the indexes of its frame lines (in frame order)."""
    path = tmp / f"good{suffix}"
    write_with_can_logger(path, frames())
    lines = path.read_text().splitlines()
    if suffix == ".asc":
        rows = [i for i, line in enumerate(lines) if " Rx " in line]
    elif suffix == ".trc":
        rows = [i for i, line in enumerate(lines) if line.strip() and not line.startswith(";")]
    else:
        rows = list(range(1, len(lines)))
    assert len(rows) == N
    return lines, rows


def read(path: Path) -> tuple[np.ndarray, list[str]]:
    src = open_log(path)
    batches = list(src.batches(max_frames=16))
    got = np.concatenate([b.frames for b in batches])
    notices = [n.detail for b in batches for n in b.notices if n.kind == "parse_error"]
    return got, notices


def save(tmp: Path, name: str, lines: list[str]) -> Path:
    path = tmp / name
    path.write_text("\n".join(lines) + "\n")
    return path


def test_negative_time_asc_lines_are_counted(tmp_path: Path) -> None:
    """27 lines with a negative time: python-can's ASCReader skips them without a word."""
    lines, rows = written(tmp_path, ".asc")
    damaged = rows[10:37]
    for i in damaged:
        lines[i] = lines[i].replace(" 0.", "-0.", 1)
    got, notices = read(save(tmp_path, "neg.asc", lines))
    assert len(got) == N - 27
    assert len(notices) == 27
    assert [f"line {i + 1}:" in d for i, d in zip(damaged, notices, strict=True)] == [True] * 27
    keep = np.r_[0:10, 37:N]
    assert np.array_equal(got["data"], frames()["data"][keep])


def test_asc_reading_goes_on_after_a_line_python_can_raises_on(tmp_path: Path) -> None:
    """A data byte 'ZZ' makes python-can raise (the generator ends): the rest is read."""
    lines, rows = written(tmp_path, ".asc")
    lines[rows[40]] = lines[rows[40]][:-2] + "ZZ"
    got, notices = read(save(tmp_path, "zz.asc", lines))
    assert len(got) == N - 1 and len(notices) == 1
    assert f"line {rows[40] + 1}:" in notices[0] and "ZZ" in notices[0]
    assert np.array_equal(got["data"], np.delete(frames()["data"], 40, axis=0))


def test_garbled_trc_id_does_not_stop_the_file(tmp_path: Path) -> None:
    """A hex ID with a 'G' in it: python-can raises at half the file; the rest is read."""
    lines, rows = written(tmp_path, ".trc")
    line = lines[rows[50]]
    lines[rows[50]] = line.replace(" 0102 ", " 01G2 ").replace(" 0101 ", " 01G1 ")
    lines[rows[50]] = lines[rows[50]].replace(" 0103 ", " 01G3 ")
    assert lines[rows[50]] != line
    lines[rows[70]] = lines[rows[70]][:30]  # cut inside: python-can only warns and drops it
    got, notices = read(save(tmp_path, "g.trc", lines))
    assert len(got) == N - 2 and len(notices) == 2
    assert f"line {rows[50] + 1}:" in notices[0] and f"line {rows[70] + 1}:" in notices[1]
    assert np.array_equal(got["id"], np.delete(frames()["id"], [50, 70]))


def test_bad_csv_line_is_counted_and_skipped(tmp_path: Path) -> None:
    lines, rows = written(tmp_path, ".csv")
    lines[rows[20]] = lines[rows[20]].replace(",8,", ",eight,")
    lines[rows[30]] = "1700000000.05,0x101"
    got, notices = read(save(tmp_path, "b.csv", lines))
    assert len(got) == N - 2 and len(notices) == 2
    assert np.array_equal(got["data"], np.delete(frames()["data"], [20, 30], axis=0))


def test_lines_that_are_not_frames_are_not_errors(tmp_path: Path) -> None:
    """Comments, bus statistics, chip status and PCAN status records are no lost frames."""
    lines, rows = written(tmp_path, ".asc")
    lines.insert(rows[5], " 0.008000 1  Statistic: D 10 R 0 XD 0 XR 0 E 0 O 0 B 1.20%")
    lines.insert(rows[5], " 0.008000 CAN 1 Status:chip status error active")
    lines.insert(rows[5], "// a comment")
    got, notices = read(save(tmp_path, "events.asc", lines))
    assert len(got) == N and notices == []

    lines, rows = written(tmp_path, ".trc")
    lines.insert(rows[5], "      4a        8.000 ST  1     -  -  -  4    00 00 00 04")
    lines.insert(rows[5], ";   a comment")
    got, notices = read(save(tmp_path, "events.trc", lines))
    assert len(got) == N and notices == []


def test_binary_noise_line_costs_one_error(tmp_path: Path) -> None:
    lines, rows = written(tmp_path, ".asc")
    noise = np.random.default_rng(2).integers(33, 127, 20_000, dtype=np.uint8).tobytes()
    lines[rows[60]] = noise.decode()
    got, notices = read(save(tmp_path, "noise.asc", lines))
    assert len(got) == N - 1 and len(notices) == 1


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    suffix=st.sampled_from([".asc", ".trc", ".csv"]),
    damage=st.lists(
        st.tuples(
            st.integers(0, N - 1),
            st.sampled_from(["cut", "char"]),
            st.integers(0, 200),
            st.sampled_from("z#@9.G"),
        ),
        min_size=1,
        max_size=8,
    ),
)
def test_every_frame_line_is_a_frame_or_an_error(
    tmp_path: Path, suffix: str, damage: list[tuple[int, str, int, str]]
) -> None:
    """Whatever single-line damage: frames read + parse errors = frame lines written."""
    lines, rows = written(tmp_path, suffix)
    for row, kind, at, char in damage:
        line = lines[rows[row]]
        first = len(line) - len(line.lstrip())
        at = first + at % (len(line) - first)
        if kind == "cut":
            lines[rows[row]] = line[: at + 1]
        else:
            lines[rows[row]] = line[:at] + char + line[at + 1 :]
    got, notices = read(save(tmp_path, f"d{suffix}", lines))
    assert len(got) + len(notices) == N, notices


@pytest.mark.parametrize("suffix", [".asc", ".trc"])
def test_replay_summary_counts_the_lines(
    tmp_path: Path, suffix: str, capsys: pytest.CaptureFixture[str]
) -> None:
    lines, rows = written(tmp_path, suffix)
    for i in rows[10:37]:
        lines[i] = lines[i].replace(" 0.", "-0.", 1) if suffix == ".asc" else lines[i][:25]
    path = save(tmp_path, f"r{suffix}", lines)
    assert main(["replay", str(path)]) == 0
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    row = [line for line in (out + err).splitlines() if line.startswith("log parse errors")]
    assert row and row[0].split()[-1] == "27", out + err


def test_asc_frame_with_garbled_channel_and_direction_is_counted(tmp_path: Path) -> None:
    """' 0.000000 z  101   zRx   d 8 CF ...': python-can skips it as an event on no CAN
    channel; its data bytes show it was a frame, so it is a parse error, not a silent loss."""
    lines, rows = written(tmp_path, ".asc")
    lines[rows[0]] = lines[rows[0]].replace(" 1  ", " z  ", 1).replace(" Rx ", "zRx ", 1)
    got, notices = read(save(tmp_path, "garbled.asc", lines))
    assert len(got) == N - 1 and len(notices) == 1


@pytest.mark.parametrize("channel", ["z", "1z", "#"])
def test_asc_frame_cut_after_a_garbled_channel_is_counted(tmp_path: Path, channel: str) -> None:
    """' 0.000000 z  101     ': one letter is no event's name, so it was a frame line."""
    lines, rows = written(tmp_path, ".asc")
    lines[rows[0]] = lines[rows[0]][:21].replace(" 1  ", f" {channel}  ", 1)
    got, notices = read(save(tmp_path, "cut.asc", lines))
    assert len(got) == N - 1 and len(notices) == 1
