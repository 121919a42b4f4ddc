"""The soak: ``python -m benchmarks.soak [--minutes 10] [--no-tui] [--json OUT]``.

The virtual board at 1 kHz x 3 channels on python-can's virtual bus for ``--minutes``,
with every fault kind of the emulator switched on and off in turn (three times round),
MCAP logging on and the TUI attached headless (polling and rendering as on a screen).

It passes when, over the whole run:

* frames sent = frames received = frames logged (the finished MCAP read back), nothing
  dropped by the runner or the logger, the MCAP file complete, and the bench kept up (every
  frame through the pipeline within 0.5 s of the board stopping: python-can's virtual bus
  queues without limit, so a bench falling behind would otherwise look lossless);
* resident memory after the warm-up (the UI history ring fills in the first minute at
  1 kHz) grows by at most ``--mem-bound-mb`` (default 64 MB); with the TUI, the run lives in
  the engine process (bench/engine/) and memory is this process's plus the engine's;
* no exception anywhere: not in any thread (``threading.excepthook``), not logged at
  ERROR by any bench module, not in the runner, the logger or the TUI (the engine process
  reports its own thread exceptions and ERROR records).

With ``--csv-fails-after-bytes N`` (without the TUI) the run also writes the live results
CSV, as ``bench run --csv`` does, to a file that takes N bytes and then refuses every write
with ENOSPC (a disk filling up mid-run). The same promises must hold, and the failure must be
loud: the runner reports it, an OUTPUT_ERROR event is in the MCAP, result rows are counted
as lost and the run's exit status (as ``bench run`` computes it) is non-zero.

It prints the figures as it goes and at the end, writes them as JSON, and exits 1 on a
failure. ``pytest -m soak`` (or ``BENCH_SOAK=1 pytest tests/test_soak.py``) runs it.
"""

from __future__ import annotations

import argparse
import errno
import io
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from bench.engine.child import ProblemLog
from benchmarks.common import machine_info, rss_mb


def fault_schedule(duration_s: float, cycles: int = 3) -> list[dict[str, Any]]:
    """Every fault kind in turn, ``cycles`` times round; each is on for 60 % of its slot."""
    from devices.emulator.scenario import FAULT_KINDS, FRAME_KINDS, SIGNAL_KINDS

    kinds = list(FAULT_KINDS)
    slot = duration_s / (cycles * len(kinds))
    faults = []
    for c in range(cycles):
        for i, kind in enumerate(kinds):
            start = (c * len(kinds) + i) * slot
            f: dict[str, Any] = {"kind": kind, "start_s": round(start, 3)}
            f["end_s"] = round(start + 0.6 * slot, 3)
            if kind in SIGNAL_KINDS:
                f["channel"] = 1 + (i + c) % 3
            elif kind in FRAME_KINDS:
                f["channel"] = [1, 2, 3, "adc", "bus", "speed", "status"][(i + c) % 7]
                if kind in ("loss", "duplicate", "reorder"):
                    f["probability"] = 0.05
                if kind == "crc":
                    f["probability"] = 0.3
            else:
                f["channel"] = "uart"
            faults.append(f)
    return faults


class FailingFile(io.RawIOBase):
    """A file that takes ``limit`` bytes, then refuses every write with ENOSPC (a full disk
    without root or a tmpfs)."""

    def __init__(self, path: str, limit: int) -> None:
        self._f = open(path, "wb")  # noqa: SIM115 - closed in close()
        self.limit, self.n = limit, 0

    def writable(self) -> bool:
        return True

    def write(self, b: Any) -> int:
        if self.n + len(b) > self.limit:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.n += len(b)
        return self._f.write(b)

    def close(self) -> None:
        self._f.close()
        super().close()


def failing_csv_opener(limit: int) -> Any:
    """A stream opener for the results CSV whose file fills up after ``limit`` bytes."""
    import pyarrow as pa

    return lambda target: pa.PythonFile(FailingFile(str(target), limit), mode="w")


def engine_rss_mb(session: Any) -> float:
    """Resident set size of the engine process a TUI session runs in (0 without one): with
    the TUI attached, the run's memory is there (bench/engine/)."""
    pid = getattr(session, "pid", None)
    if pid is None:
        return 0.0
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError):
        pass
    return 0.0


def soak(
    minutes: float,
    *,
    tui: bool = True,
    mem_bound_mb: float = 64.0,
    mcap: Path | None = None,
    csv_fails_after_bytes: int | None = None,
    log: Any = print,
) -> dict[str, Any]:
    from benchmarks.live import KEEP_UP_S, run_live

    seconds = minutes * 60.0
    warmup = min(60.0, max(5.0, 0.3 * seconds))
    faults = fault_schedule(seconds + 2.0)
    problems = ProblemLog()
    problems.install()
    mem: list[tuple[float, float]] = [(0.0, rss_mb())]
    t0 = time.monotonic()
    last_print = [0.0]

    def progress(runner: Any) -> None:
        el = time.monotonic() - t0
        mem.append((el, rss_mb() + engine_rss_mb(runner)))
        if el - last_print[0] >= 30.0:
            last_print[0] = el
            snap = runner.snapshot(last=1)
            log(
                f"  {el:6.0f} s  received {snap.frames_received:>9}  dropped "
                f"{snap.frames_dropped}  queue {snap.queue_depth:>4}  RSS {mem[-1][1]:6.1f} MB  "
                f"latency p50/p99 {snap.latency_ms[0]:.2f}/{snap.latency_ms[1]:.2f} ms"
            )

    log(
        f"soak: {minutes:g} min at 1 kHz x 3 ch, {len(faults)} fault windows "
        f"({len({f['kind'] for f in faults})} kinds), MCAP on, TUI {'on' if tui else 'off'}"
    )
    try:
        opener = (
            None if csv_fails_after_bytes is None else failing_csv_opener(csv_fails_after_bytes)
        )
        run = run_live(
            None,
            seconds,
            tui=tui,
            faults=faults,
            on_progress=progress,
            mcap_path=mcap,
            csv_opener=opener,
        )
    finally:
        problems.uninstall()
    mem.append((time.monotonic() - t0, rss_mb()))
    after = [m for t, m in mem if t >= warmup]
    base = after[0] if after else mem[-1][1]
    growth = max(after) - base if after else 0.0
    checks = {
        "frames sent = received = logged": run.sent == run.received == run.logged > 0,
        "nothing dropped": run.dropped == 0 and run.mcap_dropped == 0,
        "board sent every frame": run.board_errors == 0,
        "bench kept up (all frames through within 0.5 s of the end)": run.drain_s <= KEEP_UP_S,
        "MCAP complete": run.mcap_complete,
        f"memory growth after warm-up <= {mem_bound_mb:g} MB": growth <= mem_bound_mb,
        "no exception": not (run.errors or problems.seen),
        "ran the full time": run.seconds >= seconds and run.rate_achieved > 0,
    }
    if csv_fails_after_bytes is not None:
        # bench run's exit status: 1 when a secondary output failed or lost rows
        exit_code = 1 if (run.output_errors or run.csv_rows_lost) else 0
        checks["CSV failed mid-run (rows written, then rows lost)"] = (
            run.csv_rows > 0 and run.csv_rows_lost > 0
        )
        checks["CSV failure loud (reported, OUTPUT_ERROR logged, exit 1)"] = (
            bool(run.output_errors) and run.output_error_events > 0 and exit_code == 1
        )
    result = {
        "minutes": minutes,
        "tui": tui,
        "passed": all(checks.values()),
        "checks": checks,
        "run": run.as_dict(),
        "fault_kinds": sorted({f["kind"] for f in faults}),
        "memory_mb": {
            "start": mem[0][1],
            "after_warmup": base,
            "end": mem[-1][1],
            "max": max(m for _, m in mem),
            "growth_after_warmup": growth,
            "warmup_s": warmup,
            "timeline": [(round(t, 1), round(m, 1)) for t, m in mem[:: max(1, len(mem) // 60)]],
        },
        "exceptions": run.errors + problems.seen,
        "machine": machine_info(),
    }
    return result


def report(r: dict[str, Any], log: Any = print) -> None:
    run, mem = r["run"], r["memory_mb"]
    log(f"soak {'PASSED' if r['passed'] else 'FAILED'}: {r['minutes']:g} min, TUI {r['tui']}")
    log(
        f"  frames sent {run['sent']}  received {run['received']}  logged {run['logged']}  "
        f"dropped {run['dropped']}+{run['mcap_dropped']}  rate {run['rate_achieved']:.0f}/s"
    )
    log(
        f"  latency p50 {run['p50_ms']:.2f} ms  p99 {run['p99_ms']:.2f} ms  max "
        f"{run['max_ms']:.1f} ms  over {run['results']} results"
    )
    log(
        f"  memory start {mem['start']:.1f} MB, after {mem['warmup_s']:.0f} s warm-up "
        f"{mem['after_warmup']:.1f} MB, end {mem['end']:.1f} MB, max {mem['max']:.1f} MB, "
        f"growth {mem['growth_after_warmup']:+.1f} MB"
    )
    st = run.get("stats", {})
    shown = {k: v for k, v in st.items() if isinstance(v, int) and v}
    log(f"  bench counted: {shown}")
    log(f"  TUI snapshots applied: {run['tui_snapshots']}")
    if run.get("output_errors"):
        log(
            f"  CSV rows written {run['csv_rows']}, lost {run['csv_rows_lost']}; "
            f"{run['output_error_events']} OUTPUT_ERROR events; {run['output_errors'][0]}"
        )
    log(f"  fault kinds: {', '.join(r['fault_kinds'])}")
    for name, ok in r["checks"].items():
        log(f"  [{'x' if ok else ' '}] {name}")
    for e in r["exceptions"][:20]:
        log(f"  exception: {e}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m benchmarks.soak", description=__doc__.split("\n\n")[1]
    )
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--no-tui", action="store_true", help="without the headless TUI")
    ap.add_argument("--mem-bound-mb", type=float, default=64.0)
    ap.add_argument("--mcap", type=Path, help="keep the run's MCAP here")
    ap.add_argument("--json", metavar="OUT", default=None, help="write the figures as JSON")
    ap.add_argument(
        "--csv-fails-after-bytes",
        type=int,
        metavar="N",
        help="also write the results CSV, to a file that fails with ENOSPC after N bytes "
        "(needs --no-tui)",
    )
    args = ap.parse_args(argv)
    if args.csv_fails_after_bytes is not None and not args.no_tui:
        ap.error("--csv-fails-after-bytes needs --no-tui (the CSV is written in this process)")

    def log(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    r = soak(
        args.minutes,
        tui=not args.no_tui,
        mem_bound_mb=args.mem_bound_mb,
        mcap=args.mcap,
        csv_fails_after_bytes=args.csv_fails_after_bytes,
        log=log,
    )
    report(r, log)
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=2, default=str) + "\n")
    return 0 if r["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
