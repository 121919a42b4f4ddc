"""The result of fusion per sampling instant: one numpy row layout, and its CSV form."""

from __future__ import annotations

import io
from pathlib import Path
from typing import TextIO

import numpy as np

RESULT_DTYPE = np.dtype(
    [
        ("n", "<i8"),  # unwrapped sample index
        ("seq", "<i8"),  # arrival index of the sample's last frame
        ("ticks", "<i8"),  # unwrapped board time, 100 us ticks
        ("t", "<f8"),  # receive time of the sample's last frame, s
        ("time_s", "<f8"),  # board time from the first sample, s
        ("code", "<i4", (3,)),
        ("status", "u1", (3,)),
        ("present", "?", (3,)),
        ("acc", "<f8", (3,)),  # calibrated m/s^2; NaN where the channel is not usable
        ("slopes", "<f8", (3,)),  # g12, g23, g13 per mille (reference method)
        ("votes", "?", (3,)),  # v1, v2, v3
        ("weights", "<f8", (3,)),  # w12, w23, w13
        ("gradient", "<f8"),  # reference result per mille; NaN when invalid
        ("valid", "?"),
        # the bench's own estimator (METHOD.md section 5)
        ("gradient_signed", "<f8"),  # per mille; NaN when unavailable
        ("gradient_ls", "<f8"),  # least-squares magnitude per mille (no a_ref needed)
        ("u", "<f8"),  # specific force along the track, m/s^2
        ("w", "<f8"),  # specific force normal to the track, m/s^2
        ("a_ref", "<f8"),  # reference acceleration from SPEED_REF, m/s^2; NaN when unavailable
        ("residual", "<f8"),  # least-squares residual, m/s^2
        ("degraded", "?"),  # computed from two channels only
        ("excluded", "u1"),  # channel excluded by the estimator (1..3), 0 = none
    ]
)

CSV_COLUMNS = [
    "time_s",
    "counter",
    "a1",
    "a2",
    "a3",
    "g12",
    "g23",
    "g13",
    "v1",
    "v2",
    "v3",
    "w12",
    "w23",
    "w13",
    "gradient",
    "valid",
    "gradient_signed",
    "a_ref",
    "residual",
    "degraded",
    "excluded",
]


def _fmt(values: np.ndarray) -> list[str]:
    """Shortest round-trip text for floats (so the CSV carries float64 exactly); '' for NaN."""
    return ["" if v != v else repr(v) for v in values.tolist()]


def csv_columns(results: np.ndarray) -> list[list[str]]:
    """The CSV cells of a batch of results, column by column (in CSV_COLUMNS order)."""
    cols: list[list[str]] = [_fmt(results["time_s"]), [str(v) for v in results["n"].tolist()]]
    cols += [_fmt(results["acc"][:, k]) for k in range(3)]
    cols += [_fmt(results["slopes"][:, k]) for k in range(3)]
    cols += [[str(int(v)) for v in results["votes"][:, k].tolist()] for k in range(3)]
    cols += [_fmt(results["weights"][:, k]) for k in range(3)]
    cols += [_fmt(results["gradient"]), [str(int(v)) for v in results["valid"].tolist()]]
    cols += [_fmt(results["gradient_signed"]), _fmt(results["a_ref"]), _fmt(results["residual"])]
    cols += [[str(int(v)) for v in results["degraded"].tolist()]]
    cols += [[str(v) if v else "" for v in results["excluded"].tolist()]]
    return cols


class CsvWriter:
    """Streams result batches to a CSV file (header first, one row per sampling instant)."""

    def __init__(self, target: str | Path | TextIO) -> None:
        self._own = not isinstance(target, io.TextIOBase)
        self._fh: TextIO = open(target, "w", newline="", encoding="utf-8") if self._own else target  # type: ignore[arg-type]  # noqa: SIM115
        self._fh.write(",".join(CSV_COLUMNS) + "\n")
        self.rows = 0

    def write(self, results: np.ndarray) -> None:
        if len(results) == 0:
            return
        rows = zip(*csv_columns(results), strict=True)
        self._fh.write("".join(",".join(r) + "\n" for r in rows))
        self.rows += len(results)

    def close(self) -> None:
        if self._own:
            self._fh.close()
        else:
            self._fh.flush()

    def __enter__(self) -> CsvWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
