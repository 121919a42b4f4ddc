"""``bench log info``: what a bench MCAP file holds, in the bench's terms.

Like ``mcap info`` (duration, chunks, topics, metadata, attachments) plus what only the
bench knows: frames per ID and per decode outcome, UART link errors, source notices,
events, and the spans where votes failed or the reference gradient was invalid. One
pass over the chunks; works on unfinished files (and says what was lost).
"""

from __future__ import annotations

import json
import math
from collections import Counter
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from bench.mcaplog import schemas as S
from bench.mcaplog.decoders import link_error_from_json, notice_from_json
from bench.mcaplog.reader import McapLog
from bench.records.results import RESULT_DTYPE


def spans(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index ranges of the True runs of a boolean array."""
    if len(mask) == 0:
        return []
    m = np.concatenate(([False], mask.astype(bool), [False]))
    edges = np.flatnonzero(m[1:] != m[:-1])
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True))


def _span_rows(results: np.ndarray, mask: np.ndarray, limit: int) -> dict[str, Any]:
    found = spans(mask)
    rows = []
    for a, b in found[:limit]:
        part = results[a:b]
        failed = np.flatnonzero((~part["votes"]).any(axis=0)).tolist()
        rows.append(
            {
                "first_n": int(part["n"][0]),
                "last_n": int(part["n"][-1]),
                "samples": b - a,
                "start_time_s": float(part["time_s"][0]),
                "end_time_s": float(part["time_s"][-1]),
                "start_t": float(part["t"][0]),
                "failed_votes": [f"v{k + 1}" for k in failed],
            }
        )
    return {"count": len(found), "samples": int(np.count_nonzero(mask)), "spans": rows}


def _time(t: float) -> str:
    if not math.isfinite(t):
        return "n/a"
    if t > 1e8:  # POSIX seconds
        return datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + "Z"
    return f"{t:.6f} s"


def log_info(path: str | Path, *, verify: bool = False, max_spans: int = 20) -> dict[str, Any]:
    """Everything ``bench log info`` prints, as a JSON-able dict."""
    with McapLog(path) as lg:
        fid = lg.channel_id(S.FRAME_TOPIC)
        lid = lg.channel_id(S.LINK_ERROR_TOPIC)
        nid = lg.channel_id(S.NOTICE_TOPIC)
        rid = lg.channel_id(S.RESULT_TOPIC)
        eid = lg.channel_id(S.EVENT_TOPIC)
        by_id: Counter[int] = Counter()
        by_outcome: Counter[str] = Counter()
        uart = 0
        t_first, t_last = math.inf, -math.inf
        link: Counter[str] = Counter()
        notices: Counter[str] = Counter()
        events: Counter[str] = Counter()
        result_msgs: list[memoryview] = []
        counts: Counter[int] = Counter()
        for content in lg.iter_chunks():
            for cid, offs in content.offsets.items():
                counts[cid] += len(offs)
            if fid is not None:
                recs = lg.frame_records(content)
                if len(recs):
                    p = recs["payload"]
                    ids, c = np.unique(p["id"], return_counts=True)
                    by_id.update(dict(zip(ids.tolist(), c.tolist(), strict=True)))
                    oc, c = np.unique(p["outcome"], return_counts=True)
                    by_outcome.update(
                        {S.outcome_name(o): k for o, k in zip(oc.tolist(), c.tolist(), strict=True)}
                    )
                    uart += int(np.count_nonzero(p["uart"]))
                    t = p["t"][np.isfinite(p["t"])]
                    if len(t):
                        t_first = min(t_first, float(t.min()))
                        t_last = max(t_last, float(t.max()))
            if lid is not None:
                link.update(
                    S.outcome_name(int(e.outcome))
                    for e in map(link_error_from_json, content.payloads(lid))
                )
            if nid is not None:
                notices.update(n.kind for n in map(notice_from_json, content.payloads(nid)))
            if eid is not None:
                events.update(
                    json.loads(bytes(m)).get("kind_name", "?") for m in content.payloads(eid)
                )
            if rid is not None:
                result_msgs += content.payloads(rid)
        results = S.decode_rows(result_msgs, S.RESULT_COLUMNS, RESULT_DTYPE)
        info: dict[str, Any] = {
            "file": str(lg.path),
            "size_bytes": lg.size,
            "library": lg.library,
            "complete": lg.complete,
            "truncated": lg.truncated,
            "lost_bytes": lg.lost_bytes,
            "warnings": list(lg.warnings),
            "chunks": len(lg.chunks),
            "compression": sorted({c.compression or "none" for c in lg.chunks}),
            "first_frame_t": t_first if math.isfinite(t_first) else None,
            "last_frame_t": t_last if math.isfinite(t_last) else None,
            "duration_s": (t_last - t_first) if math.isfinite(t_first) else 0.0,
            "frames": sum(by_id.values()),
            "frames_by_id": {f"0x{k:03X}": v for k, v in sorted(by_id.items())},
            "frames_by_outcome": dict(sorted(by_outcome.items())),
            "uart_frames": uart,
            "link_errors": dict(sorted(link.items())),
            "notices": dict(sorted(notices.items())),
            "events": dict(sorted(events.items())),
            "results": len(results),
            "valid": int(np.count_nonzero(results["valid"])) if len(results) else 0,
            "vote_failures": _span_rows(
                results, np.logical_not(results["votes"].all(axis=1)), max_spans
            )
            if len(results)
            else {"count": 0, "samples": 0, "spans": []},
            "invalid": _span_rows(results, ~results["valid"], max_spans)
            if len(results)
            else {"count": 0, "samples": 0, "spans": []},
            "topics": lg.per_topic(counts),
            "metadata": lg.metadata_dict(),
            "attachments": [
                {"name": a.name, "media_type": a.media_type, "size": a.size} for a in lg.attachments
            ],
        }
        if verify:
            info["crc_problems"] = lg.verify()
        return info


def _short(value: str, width: int = 72) -> str:
    first = value.splitlines()[0] if value else ""
    more = len(value) > len(first)
    if len(first) > width:
        return first[: width - 3] + "..."
    return first + (f"  [{len(value)} chars]" if more else "")


def format_info(info: dict[str, Any]) -> str:
    """The human-readable report."""
    out: list[str] = []
    add = out.append
    state = (
        "complete"
        if info["complete"]
        else ("UNFINISHED/TRUNCATED" if info["truncated"] else "no valid summary")
    )
    add(f"file:        {info['file']}  ({info['size_bytes']} bytes, {state})")
    for w in info["warnings"]:
        add(f"warning:     {w}")
    add(f"library:     {info['library']}")
    ft, lt = info["first_frame_t"], info["last_frame_t"]
    first = _time(ft if ft is not None else math.nan)
    last = _time(lt if lt is not None else math.nan)
    add(f"duration:    {info['duration_s']:.3f} s  ({first} .. {last})")
    add(f"chunks:      {info['chunks']}  ({', '.join(info['compression']) or '-'})")
    add(f"frames:      {info['frames']}  ({info['uart_frames']} via UART)")
    for k, v in info["frames_by_id"].items():
        add(f"  id {k}:   {v}")
    add(
        "outcomes:    "
        + (", ".join(f"{k} {v}" for k, v in info["frames_by_outcome"].items()) or "-")
    )
    add("link errors: " + (", ".join(f"{k} {v}" for k, v in info["link_errors"].items()) or "0"))
    if info["notices"]:
        add("notices:     " + ", ".join(f"{k} {v}" for k, v in info["notices"].items()))
    if info["events"]:
        add("events:      " + ", ".join(f"{k} {v}" for k, v in info["events"].items()))
    if info["results"]:
        frac = info["valid"] / info["results"]
        add(f"results:     {info['results']}  (valid {info['valid']}, {100 * frac:.2f} %)")
        for key, title in (("vote_failures", "vote-failure spans"), ("invalid", "invalid spans")):
            block = info[key]
            add(f"{title}: {block['count']} ({block['samples']} samples)")
            for s in block["spans"]:
                votes = f" failed {','.join(s['failed_votes'])}" if key == "vote_failures" else ""
                add(
                    f"  n {s['first_n']}..{s['last_n']} ({s['samples']} samples)  "
                    f"time_s {s['start_time_s']:.4f}..{s['end_time_s']:.4f}{votes}"
                )
            if block["count"] > len(block["spans"]):
                add(f"  ... and {block['count'] - len(block['spans'])} more")
    else:
        add("results:     none recorded (bench replay recomputes them from the frames)")
    cal = info["metadata"].get("config")
    add(
        "calibration: "
        + (cal.get("described", cal.get("source", "?")) if cal else "none recorded (nominal ICD)")
    )
    add("topics:")
    for topic, n in info["topics"].items():
        add(f"  {topic:<20} {n}")
    if info["metadata"]:
        add("metadata:")
        for name, data in info["metadata"].items():
            add(f"  [{name}]")
            for k, v in data.items():
                add(f"    {k} = {_short(v)}")
    if info["attachments"]:
        add("attachments:")
        for a in info["attachments"]:
            add(f"  {a['name']}  ({a['media_type']}, {a['size']} bytes)")
    if "crc_problems" in info:
        add(
            "crc check:   "
            + ("all CRCs ok" if not info["crc_problems"] else "; ".join(info["crc_problems"]))
        )
    return "\n".join(out)
