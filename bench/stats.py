"""Running counters of everything the pipeline saw: what the TUI, `log info` and reports show."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from bench.events import EventKind


@dataclass
class ChannelStats:
    frames: int = 0  # valid frames of this channel
    crc_errors: int = 0
    gaps: int = 0  # samples closed without this channel
    duplicates: int = 0
    late: int = 0
    status_flagged: int = 0
    counter_jumps: int = 0
    first_t: float = float("nan")
    last_t: float = float("nan")

    def rate_hz(self) -> float:
        """Frame rate from elapsed receive time (not UI ticks)."""
        span = self.last_t - self.first_t
        return (self.frames - 1) / span if self.frames > 1 and span > 0 else 0.0


@dataclass
class Stats:
    frames: int = 0  # every frame received, good or bad
    frames_by_id: Counter[int] = field(default_factory=Counter)
    channels: list[ChannelStats] = field(default_factory=lambda: [ChannelStats() for _ in range(3)])
    crc_errors: int = 0
    wrong_dlc: int = 0
    unknown_id: int = 0
    link_errors: int = 0
    parse_errors: int = 0
    samples: int = 0
    valid: int = 0
    degraded: int = 0
    vote_failures: list[int] = field(
        default_factory=lambda: [0, 0, 0]
    )  # samples failing v1, v2, v3
    samples_lost: int = 0
    status_frames: int = 0
    speed_frames: int = 0
    events: Counter[int] = field(default_factory=Counter)

    def count_frames(self, ids: np.ndarray) -> None:
        self.frames += len(ids)
        if len(ids) <= 16:  # a live batch: cheaper without numpy's fixed costs
            self.frames_by_id.update(ids.tolist())
        else:
            u, c = np.unique(ids, return_counts=True)
            self.frames_by_id.update(dict(zip(u.tolist(), c.tolist(), strict=True)))

    def count_events(self, events: np.ndarray) -> None:
        if len(events) == 0:
            return
        kinds = events["kind"]
        self.events.update(
            dict(zip(*(a.tolist() for a in np.unique(kinds, return_counts=True)), strict=True))
        )
        per_channel = {
            EventKind.CRC_ERROR: "crc_errors",
            EventKind.GAP: "gaps",
            EventKind.DUPLICATE: "duplicates",
            EventKind.LATE: "late",
            EventKind.STATUS_FLAG: "status_flagged",
            EventKind.COUNTER_JUMP: "counter_jumps",
        }
        for kind, attr in per_channel.items():
            sel = events["channel"][kinds == kind]
            if len(sel):
                counts = np.bincount(sel, minlength=4)
                for ch in range(3):
                    setattr(
                        self.channels[ch],
                        attr,
                        getattr(self.channels[ch], attr) + int(counts[ch + 1]),
                    )
        self.crc_errors += int(np.count_nonzero(kinds == EventKind.CRC_ERROR))
        self.wrong_dlc += int(np.count_nonzero(kinds == EventKind.WRONG_DLC))
        self.unknown_id += int(np.count_nonzero(kinds == EventKind.UNKNOWN_ID))
        self.link_errors += int(np.count_nonzero(kinds == EventKind.LINK_ERROR))
        self.parse_errors += int(np.count_nonzero(kinds == EventKind.PARSE_ERROR))
        self.samples_lost += int(events["value"][kinds == EventKind.SAMPLES_LOST].sum())

    def count_results(self, results: np.ndarray) -> None:
        self.samples += len(results)
        self.valid += int(np.count_nonzero(results["valid"]))
        self.degraded += int(np.count_nonzero(results["degraded"]))
        fails = np.count_nonzero(~results["votes"], axis=0)
        for k in range(3):
            self.vote_failures[k] += int(fails[k])

    def as_dict(self) -> dict[str, object]:
        return {
            "frames": self.frames,
            "frames_by_id": {f"0x{k:03X}": v for k, v in sorted(self.frames_by_id.items())},
            "crc_errors": self.crc_errors,
            "wrong_dlc": self.wrong_dlc,
            "unknown_id": self.unknown_id,
            "link_errors": self.link_errors,
            "parse_errors": self.parse_errors,
            "samples": self.samples,
            "valid": self.valid,
            "valid_fraction": self.valid / self.samples if self.samples else 0.0,
            "degraded": self.degraded,
            "vote_failures": list(self.vote_failures),
            "samples_lost": self.samples_lost,
            "channels": [
                {k: v for k, v in vars(c).items() if k not in ("first_t", "last_t")}
                for c in self.channels
            ],
        }
