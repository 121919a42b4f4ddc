"""Event arrays: building, ordering and counting, on the live (few) and replay (many) paths.

concat_events promises the stable sort by time of the parts' concatenation (NaN last;
a single part is returned as it is);
its fast paths (Python for a few events, a linear merge of ordered parts) must give
exactly that. The reference here is a plain Python stable sort of the rows.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.pipeline.stats import Stats
from bench.records.events import EVENT_DTYPE, EventKind, concat_events, make_events

times = st.sampled_from([0.0, -0.0, 0.5, 1.0, 1.0, 2.0, math.inf, -math.inf, math.nan])


@st.composite
def event_parts(draw: st.DrawFn) -> list[np.ndarray]:
    parts = []
    for p in range(draw(st.integers(0, 4))):
        t = draw(st.lists(times, max_size=draw(st.sampled_from([3, 12, 40]))))
        if draw(st.integers(0, 4)):  # mostly in time order, as the pipeline's parts are
            t = sorted(t, key=lambda x: (x != x, x))
        part = np.zeros(len(t), dtype=EVENT_DTYPE)
        part["t"] = t
        part["kind"] = p + 1
        part["n"] = np.arange(len(t))
        parts.append(part)
    return parts


def reference(parts: list[np.ndarray]) -> bytes:
    """Stable sort by time, NaN last; one part alone is taken as it is."""
    rows = [row for p in parts for row in p.tolist()]
    if sum(1 for p in parts if len(p)) > 1:
        rows.sort(key=lambda r: (math.isnan(r[0]), r[0]))
    return np.array(rows, dtype=EVENT_DTYPE).tobytes()


@settings(max_examples=300, deadline=None)
@given(event_parts())
def test_concat_events_is_the_stable_sort_by_time(parts: list[np.ndarray]) -> None:
    out = concat_events(parts)
    assert out.dtype == EVENT_DTYPE
    assert out.tobytes() == reference(parts)


def test_concat_events_of_long_ordered_parts_interleaves_them() -> None:
    a = make_events(EventKind.VOTE_FAIL, np.arange(100.0), 0, np.arange(100), 1)
    b = make_events(EventKind.INVALID, np.array([5.0, 5.0, 50.0]), 0, np.array([5, 5, 50]))
    out = concat_events([a, b])
    assert out["kind"][5:8].tolist() == [EventKind.VOTE_FAIL, EventKind.INVALID, EventKind.INVALID]
    assert out["t"][:8].tolist() == [0, 1, 2, 3, 4, 5, 5, 5]
    assert len(out) == 103 and np.all(np.diff(out["t"]) >= 0)


def test_make_events_broadcasts_scalars_and_wraps_like_a_cast() -> None:
    ev = make_events(EventKind.GAP, np.array([1.5, 2.5]), np.array([1, 3]), 7)
    assert ev.tolist() == [(1.5, 6, 1, 7, 0), (2.5, 6, 3, 7, 0)]
    one = make_events(EventKind.MARK, 3.0)
    assert one.tolist() == [(3.0, 14, 0, -1, 0)]
    assert make_events(EventKind.GAP, np.array([0.0]), -1)["channel"].tolist() == [255]
    assert len(make_events(EventKind.LATE, np.zeros(0))) == 0


def hand_made_events() -> np.ndarray:
    rows = [
        (0.1, EventKind.CRC_ERROR, 2, -1, 0x102),
        (0.2, EventKind.CRC_ERROR, 0, -1, 0x100),
        (0.3, EventKind.GAP, 3, 10, 0),
        (0.4, EventKind.GAP, 3, 11, 0),
        (0.5, EventKind.SAMPLES_LOST, 0, 12, 4),
        (0.6, EventKind.SAMPLES_LOST, 0, 20, 1),
        (0.7, EventKind.LINK_ERROR, 0, -1, 5),
        (0.8, EventKind.DUPLICATE, 1, 30, 0),
        (0.9, EventKind.COUNTER_JUMP, 1, 31, -3),
        (1.0, EventKind.VOTE_FAIL, 0, 32, 6),
    ]
    return np.array(rows * 3, dtype=EVENT_DTYPE)  # 30 rows: more than a live step's few


def test_count_events_hand_computed_on_both_paths() -> None:
    events = hand_made_events()
    whole, one_by_one = Stats(), Stats()
    whole.count_events(events)
    for i in range(len(events)):
        one_by_one.count_events(events[i : i + 1])
    for stats in (whole, one_by_one):
        assert stats.crc_errors == 6
        assert stats.samples_lost == 15
        assert stats.link_errors == 3
        assert [c.crc_errors for c in stats.channels] == [0, 3, 0]
        assert [c.gaps for c in stats.channels] == [0, 0, 6]
        assert [c.duplicates for c in stats.channels] == [3, 0, 0]
        assert [c.counter_jumps for c in stats.channels] == [3, 0, 0]
        assert stats.events[EventKind.GAP] == 6 and stats.events[EventKind.VOTE_FAIL] == 3
    assert whole.as_dict() == one_by_one.as_dict()
    assert whole.events == one_by_one.events
