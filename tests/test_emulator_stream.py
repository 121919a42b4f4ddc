"""The emulator in time chunks (issue 16 item 6): ``bench emulate --out`` streams.

* simulate_chunks gives simulate()'s frames, truth, UART bytes and summary bit for bit, with
  chunks small enough to cut through every fault window (the expectation is simulate(),
  the whole-run computation the rest of the bench and its tests rest on);
* ``bench emulate`` writes the same files byte for byte as the whole-run writers;
* its peak memory does not grow with the run's length (a 3 600 s run at 1 kHz took 4 GB).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bench.cli import main
from benchmarks.soak import fault_schedule
from devices.emulator import load_scenario, scenario_from_dict, simulate
from devices.emulator.player import write_truth_csv
from devices.emulator.stream import RunCounts, simulate_chunks
from devices.errors import BenchError
from devices.writers import write_candump
from tests.helpers import scenario_toml

ROOT = Path(__file__).resolve().parent.parent


def every_fault(seconds: float = 6.0, seed: int = 4) -> dict[str, Any]:
    """500 Hz, each fault kind (the soak's schedule), plus spikes on all channels at once,
    wide spikes, and a stuck channel from the run's first sample."""
    faults = fault_schedule(seconds, cycles=2)
    faults += [
        {
            "kind": "spike",
            "channel": "adc",
            "start_s": 0.4,
            "end_s": 5.0,
            "rate_hz": 30.0,
            "width_samples": 7,
        },
        {"kind": "spike", "channel": 2, "start_s": 0.0, "end_s": seconds, "rate_hz": 200.0},
        {"kind": "stuck", "channel": 3, "start_s": 0.0, "end_s": 0.7},
        {"kind": "crc", "channel": "adc", "start_s": 1.0, "end_s": 4.0, "probability": 0.2},
        {
            "kind": "reorder",
            "channel": "bus",
            "start_s": 0.0,
            "end_s": seconds,
            "probability": 0.1,
            "depth": 5,
        },
    ]
    return {"duration_s": seconds, "sample_rate_hz": 500, "seed": seed, "faults": faults}


def _chunked(sc: Any, chunk_s: float) -> tuple[np.ndarray, np.ndarray, bytes, str]:
    counts = RunCounts(sc)
    chunks = list(simulate_chunks(sc, uart=True, chunk_s=chunk_s, counts=counts))
    frames = np.concatenate([c.frames for c in chunks])
    truth = np.concatenate([c.truth for c in chunks])
    return frames, truth, b"".join(c.uart for c in chunks), counts.summary()


@pytest.mark.parametrize(
    "scenario", ["every_fault", "link_faults", "channel_faults", "wrap", "metro_vibration"]
)
def test_chunks_are_the_whole_run(scenario: str) -> None:
    if scenario == "every_fault":
        sc = scenario_from_dict(every_fault(), "every_fault")
        sizes = (0.011, 0.37, 2.5)
    else:
        sc = load_scenario(scenario)
        sizes = (1.7,)
    sim = simulate(sc)
    uart = sim.uart_bytes()
    for chunk_s in sizes:
        frames, truth, got_uart, summary = _chunked(sc, chunk_s)
        assert frames.tobytes() == sim.frames.tobytes(), chunk_s
        assert truth.tobytes() == sim.truth.tobytes(), chunk_s
        assert got_uart == uart, chunk_s
        assert summary == sim.summary(), chunk_s


def test_bench_emulate_files_are_the_whole_runs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sc_path = tmp_path / "every_fault.toml"
    sc_path.write_text(scenario_toml(every_fault(seconds=25.0)))  # three 10 s chunks
    sc = load_scenario(sc_path)
    sim = simulate(sc)
    summary = sim.summary()  # of a .log run: before the UART stream is made for the .bin
    write_candump(tmp_path / "whole.log", sim.frames)
    (tmp_path / "whole.bin").write_bytes(sim.uart_bytes())
    write_truth_csv(tmp_path / "whole.csv", sim.truth)

    args = ["emulate", str(sc_path), "--truth", str(tmp_path / "s.csv")]
    assert main([*args, "--out", str(tmp_path / "s.log")]) == 0
    out = capsys.readouterr().out
    assert summary in out
    assert f"wrote {len(sim.frames)} CAN frames to " in out
    assert main(["emulate", str(sc_path), "--out", str(tmp_path / "s.bin"), "-q"]) == 0
    for name in ("log", "bin", "csv"):
        got = (tmp_path / f"s.{name}").read_bytes()
        assert got == (tmp_path / f"whole.{name}").read_bytes(), name

    assert main(["emulate", str(sc_path), "--out", str(tmp_path / "s.mcap"), "-q"]) == 0
    from bench.mcaplog.reader import McapLog

    with McapLog(tmp_path / "s.mcap") as log:
        frames, _, _ = log.read_frames()
        assert frames.tobytes() == sim.frames.tobytes()


def _peak_rss_mb(tmp: Path, seconds: int) -> float:
    """Peak resident memory of a `bench emulate` child writing a 1 kHz run of ``seconds``."""
    sc = tmp / f"run{seconds}.toml"
    sc.write_text(f"duration_s = {seconds}\nsample_rate_hz = 1000\nseed = 2\n")
    out = tmp / f"run{seconds}.log"
    cmd = [sys.executable, "-m", "bench", "emulate", str(sc), "--out", str(out), "-q"]
    cmd += ["--truth", str(tmp / f"run{seconds}.csv")]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode() if proc.stderr else ""
    assert proc.returncode == 0, err
    assert out.stat().st_size > seconds * 3000 * 30  # the file really holds the run
    out.unlink()
    return usage.ru_maxrss / 1024.0


def test_emulate_memory_does_not_grow_with_the_run(tmp_path: Path) -> None:
    """240 s at 1 kHz (734 400 frames) vs 20 s: the whole-run emulate took 335 MB vs 62 MB;
    streamed, both stay within a few MB of each other."""
    short = _peak_rss_mb(tmp_path, 20)
    long = _peak_rss_mb(tmp_path, 240)
    assert long - short < 40.0, f"peak RSS {short:.0f} MB for 20 s, {long:.0f} MB for 240 s"


def test_spike_duty_is_bounded_with_the_bound_in_the_message() -> None:
    """rate_hz x width_samples past 1000 would add pulses over every sample many times
    (and cost that many additions): refused, naming the bound."""
    fault = {
        "kind": "spike",
        "channel": 1,
        "start_s": 0.0,
        "end_s": 1.0,
        "rate_hz": 500.0,
        "width_samples": 3,
    }
    with pytest.raises(BenchError, match=r"rate_hz: x width_samples must be <= 1000.*500 x 3"):
        scenario_from_dict({"duration_s": 1.0, "faults": [fault]}, "sc")
    fault["width_samples"] = 2  # exactly at the bound: accepted
    scenario_from_dict({"duration_s": 1.0, "faults": [fault]}, "sc")
