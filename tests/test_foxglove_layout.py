"""docs/foxglove/bench-layout.json opens our MCAP files ready to read: it is the app's own
layout format, and every message path in it resolves to a value in the messages of a real
run's MCAP file (results, health, status, events) or an emulator file (truth). The paths are
resolved the way Foxglove reads them (topic, then fields and [index]), on decoded JSON."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

from bench.config import Config
from bench.mcaplog.emulation import write_emulation
from bench.mcaplog.recorded import read_topic
from bench.mcaplog.sink import McapSink
from devices.base import SourceBatch
from tests.test_mcap_support import emulated, run_pipeline

LAYOUT = Path(__file__).resolve().parents[1] / "docs" / "foxglove" / "bench-layout.json"
_PART = re.compile(r"\.([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]")


def layout() -> dict[str, Any]:
    return json.loads(LAYOUT.read_text(encoding="utf-8"))


def message_paths(doc: dict[str, Any]) -> list[str]:
    out = []
    for cfg in doc["configById"].values():
        out += [p["value"] for p in cfg.get("paths", [])]
        out += [cfg[k] for k in ("topicPath", "topicToRender") if k in cfg]
    return out


def split_path(path: str) -> tuple[str, list[str | int]]:
    """'/bench/health.channels[0].gaps' -> ('/bench/health', ['channels', 0, 'gaps'])."""
    m = re.match(r"(/[A-Za-z0-9_/]+)(.*)$", path)
    assert m, path
    topic, rest = m.group(1), m.group(2)
    parts: list[str | int] = []
    pos = 0
    for part in _PART.finditer(rest):
        assert part.start() == pos, f"unreadable path {path!r}"
        parts.append(part.group(1) if part.group(1) else int(part.group(2)))
        pos = part.end()
    assert pos == len(rest), f"unreadable path {path!r}"
    return topic, parts


def resolve(message: Any, parts: list[str | int]) -> Any:
    for p in parts:
        if isinstance(p, int):
            if not isinstance(message, list) or p >= len(message):
                return KeyError
            message = message[p]
        else:
            if not isinstance(message, dict) or p not in message:
                return KeyError
            message = message[p]
    return message


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[dict[str, Any]]]:
    """Messages per topic of a run's MCAP file (an emulated run with every fault kind, fed
    through the pipeline into the live MCAP sink) and of the emulator's own file (truth)."""
    tmp = tmp_path_factory.mktemp("layout")
    sim = emulated(14.0)
    run_path, emu_path = tmp / "run.mcap", tmp / "emu.mcap"
    sink = McapSink(run_path, Config())
    step = 600
    batches = [SourceBatch(sim.frames[i : i + step]) for i in range(0, len(sim.frames), step)]
    run_pipeline(batches, sinks=[sink])
    sink.mark(float(sim.frames["t"][-1]), "operator mark 1")
    sink.close()
    write_emulation(emu_path, [sim], sim.scenario)
    topics: dict[str, list[dict[str, Any]]] = {}
    for path in (run_path, emu_path):
        for topic in _topics_in_layout():
            topics.setdefault(topic, []).extend(read_topic(path, topic))
    return topics


def _topics_in_layout() -> set[str]:
    return {split_path(p)[0] for p in message_paths(layout())}


def test_layout_is_the_apps_export_format() -> None:
    doc = layout()
    assert set(doc) >= {"configById", "layout", "globalVariables", "userNodes"}
    ids = set(doc["configById"])
    kinds = {i.split("!")[0] for i in ids}
    # per-pair values and votes, reference vs estimator vs truth, channel health, events
    assert {"Plot", "StateTransitions", "RosOut"} <= kinds

    def leaves(node: Any) -> list[str]:
        if isinstance(node, str):
            return [node]
        assert node["direction"] in ("row", "column") and 0 < node["splitPercentage"] < 100
        return leaves(node["first"]) + leaves(node["second"])

    shown = leaves(doc["layout"])
    assert sorted(shown) == sorted(ids)  # every panel placed once, none dangling


def test_every_path_resolves_in_our_mcap_files(recorded: dict[str, list[dict[str, Any]]]) -> None:
    paths = message_paths(layout())
    assert len(paths) >= 20
    for path in paths:
        topic, parts = split_path(path)
        messages = recorded.get(topic)
        assert messages, f"{path}: no messages on {topic} in our files"
        if not parts:
            continue
        values = [resolve(m, parts) for m in messages]
        assert any(v is not KeyError for v in values), f"{path}: no such field"
        numeric = [v for v in values if isinstance(v, int | float | str | bool) or v is None]
        assert numeric, f"{path}: not a plottable value"


def test_the_layout_file_is_what_the_generator_writes(tmp_path: Path) -> None:
    import runpy

    module = runpy.run_path(str(LAYOUT.with_name("make_layout.py")))
    assert json.loads(json.dumps(module["layout"]())) == layout()
