"""Writes docs/foxglove/bench-layout.json, the Foxglove layout for the bench's MCAP files and
its live stream (``bench run/tui ... --foxglove``): ``python docs/foxglove/make_layout.py``.

The layout is the app's own export format (``configById`` + a mosaic ``layout`` tree), so
Foxglove's "Import from file..." takes it as it is. Every message path is built from the
topic names in bench/mcaplog/schemas.py, and tests/test_foxglove_layout.py checks each one
against the topics' JSON schemas, so a renamed field cannot leave the layout silently empty.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from bench.mcaplog import schemas as S  # noqa: E402

OUT = Path(__file__).with_name("bench-layout.json")


def series(path: str, label: str, color: str | None = None) -> dict[str, Any]:
    s: dict[str, Any] = {
        "value": path,
        "enabled": True,
        "timestampMethod": "receiveTime",
        "label": label,
    }
    if color:
        s["color"] = color
    return s


def plot(title: str, paths: list[dict[str, Any]], **extra: Any) -> dict[str, Any]:
    return {
        "title": title,
        "paths": paths,
        "showXAxisLabels": True,
        "showYAxisLabels": True,
        "showLegend": True,
        "legendDisplay": "top",
        "showPlotValuesInLegend": True,
        "isSynced": True,
        "xAxisVal": "timestamp",
        "followingViewWidth": 30,
        **extra,
    }


def layout() -> dict[str, Any]:
    r, h, st = S.RESULT_TOPIC, S.HEALTH_TOPIC, S.STATUS_TOPIC
    config: dict[str, Any] = {
        "Plot!gradient": plot(
            "Gradient ‰: reference method vs estimator vs truth",
            [
                series(f"{r}.gradient", "reference (device method)", "#ffffff"),
                series(f"{r}.gradient_signed", "estimator (signed)", "#50d050"),
                series(f"{r}.gradient_ls", "estimator |LS|", "#2f7f2f"),
                series(f"{S.TRUTH_TOPIC}.gradient_permil", "truth (emulator files)", "#ff8040"),
            ],
        ),
        "Plot!pairs": plot(
            "Per-pair gradients ‰",
            [
                series(f"{r}.g12", "g12", "#00c8ff"),
                series(f"{r}.g23", "g23", "#d070ff"),
                series(f"{r}.g13", "g13", "#ffc400"),
            ],
            minYValue=-60,
            maxYValue=60,
        ),
        "StateTransitions!votes": {
            "title": "Votes, validity, exclusion",
            "paths": [
                {"value": f"{r}.v1", "timestampMethod": "receiveTime", "label": "v1 (g12~g23)"},
                {"value": f"{r}.v2", "timestampMethod": "receiveTime", "label": "v2 (g23~g13)"},
                {"value": f"{r}.v3", "timestampMethod": "receiveTime", "label": "v3 (g12~g13)"},
                {"value": f"{r}.valid", "timestampMethod": "receiveTime", "label": "valid"},
                {"value": f"{r}.degraded", "timestampMethod": "receiveTime", "label": "degraded"},
                {"value": f"{r}.excluded", "timestampMethod": "receiveTime", "label": "excluded"},
                {"value": f"{st}.state_name", "timestampMethod": "receiveTime", "label": "board"},
            ],
            "isSynced": True,
        },
        "Plot!accel": plot(
            "Calibrated acceleration m/s²",
            [
                series(f"{r}.a1", "ch1", "#00c8ff"),
                series(f"{r}.a2", "ch2", "#d070ff"),
                series(f"{r}.a3", "ch3", "#ffc400"),
                series(f"{r}.a_ref", "a_ref (SPEED_REF)", "#ffffff"),
            ],
        ),
        "Plot!health": plot(
            "Channel health (running counts)",
            [
                *(
                    series(f"{h}.channels[{k}].{name}", f"ch{k + 1} {name}")
                    for k in range(3)
                    for name in ("gaps", "crc_errors", "status_flagged")
                ),
                series(f"{h}.dropped_frames", "dropped frames", "#ff4040"),
                series(f"{h}.samples_lost", "samples lost", "#ff8040"),
            ],
        ),
        "Plot!rates": plot(
            "Frame rate per channel, Hz",
            [series(f"{h}.channels[{k}].rate_hz", f"ch{k + 1}") for k in range(3)],
        ),
        "RawMessages!status": {
            "title": "Board status (BOARD_STATUS)",
            "topicPath": S.STATUS_TOPIC,
            "diffEnabled": False,
            "expansion": "all",
        },
        "RosOut!events": {
            "title": "Events and operator marks",
            "searchTerms": [],
            "minLogLevel": 1,
            "topicToRender": S.EVENT_TOPIC,
        },
    }
    tree = {
        "direction": "row",
        "splitPercentage": 62,
        "first": {
            "direction": "column",
            "splitPercentage": 36,
            "first": "Plot!gradient",
            "second": {
                "direction": "column",
                "splitPercentage": 45,
                "first": "Plot!pairs",
                "second": {
                    "direction": "column",
                    "splitPercentage": 55,
                    "first": "StateTransitions!votes",
                    "second": "Plot!accel",
                },
            },
        },
        "second": {
            "direction": "column",
            "splitPercentage": 30,
            "first": {
                "direction": "row",
                "splitPercentage": 55,
                "first": "Plot!health",
                "second": "Plot!rates",
            },
            "second": {
                "direction": "column",
                "splitPercentage": 35,
                "first": "RawMessages!status",
                "second": "RosOut!events",
            },
        },
    }
    return {
        "configById": config,
        "globalVariables": {},
        "userNodes": {},
        "linkedGlobalVariables": [],
        "playbackConfig": {"speed": 1},
        "layout": tree,
    }


def main() -> None:
    OUT.write_text(json.dumps(layout(), indent=2, ensure_ascii=False) + "\n", encoding="utf-8")
    print(f"wrote {OUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
