"""Writes docs/img/tui-demo.svg (and .png when rsvg-convert is installed): the TUI on `bench demo`.

``python docs/make_tui_screenshot.py [--at 150] [--speed 5] [--size 140x42]`` runs the demo
stack exactly as `bench demo` does (the engine process with the virtual board, the App
headless in this process), plays the demo scenario ``--speed`` times faster until ``--at``
seconds of scenario time, presses ``m`` once on the way, and saves Textual's own SVG export
of the screen. No recording is kept (the log goes to a temporary folder).
"""

from __future__ import annotations

import argparse
import asyncio
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

OUT = ROOT / "docs" / "img" / "tui-demo.svg"


async def _drive(
    app: object, session: object, at_s: float, speed: float, size: tuple[int, int]
) -> str:
    async with app.run_test(size=size) as pilot:  # type: ignore[attr-defined]
        start = time.monotonic()
        marked = False
        while True:
            await asyncio.sleep(0.25)
            snap = app.last_snapshot  # type: ignore[attr-defined]
            t = float(snap.results["time_s"][-1]) if snap is not None and len(snap.results) else 0.0
            if not marked and t >= 0.6 * at_s:
                await pilot.press("m")
                marked = True
            if t >= at_s or time.monotonic() - start > 2 * at_s / speed + 60:
                break
        await asyncio.sleep(1.5)  # one more plot drawing
        svg: str = app.export_screenshot(title="bench demo")  # type: ignore[attr-defined]
        await pilot.press("q")
        while app.is_running:  # type: ignore[attr-defined]
            await asyncio.sleep(0.1)
        return svg


def main(argv: list[str] | None = None) -> int:
    from bench.commands.demo import DEMO_SCENARIO
    from bench.config_choice import scenario_config
    from bench.engine.client import start_engine
    from bench.engine.plans import EmulatorPlan
    from bench.tui.app import BenchApp

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--at", type=float, default=150.0, help="scenario time of the picture, s")
    p.add_argument("--speed", type=float, default=5.0, help="emulator time factor")
    p.add_argument("--size", default="140x42", help="terminal size COLSxROWS")
    a = p.parse_args(argv)
    cols, rows = (int(x) for x in a.size.split("x"))
    with tempfile.TemporaryDirectory(prefix="bench-shot-") as tmp:
        args = argparse.Namespace(mcap=str(Path(tmp) / "demo.mcap"), no_log=False)
        plan = EmulatorPlan(
            config=scenario_config(DEMO_SCENARIO),
            args=args,
            log_dir=Path(tmp),
            scenario=DEMO_SCENARIO,
            speed=a.speed,
        )
        session = start_engine(plan)
        try:
            svg = asyncio.run(_drive(BenchApp(session), session, a.at, a.speed, (cols, rows)))
        finally:
            session.stop()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(svg, encoding="utf-8")
    print(f"wrote {OUT.relative_to(ROOT)}")
    if shutil.which("rsvg-convert"):
        png = OUT.with_suffix(".png")
        # rsvg drops a text run's leading no-break spaces unless told to keep white space
        keep = svg.replace("<svg ", '<svg xml:space="preserve" ', 1).encode()
        cmd = ["rsvg-convert", "-w", str(cols * 10), "-o", str(png)]
        subprocess.run(cmd, input=keep, check=True)
        print(f"wrote {png.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
