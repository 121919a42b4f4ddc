"""``bench replay FILE.mcap --compare``: where recomputed results differ from the recorded ones.

Rows are matched by sample index ``n`` (so a truncated recording or a config that makes
assembly emit different samples still lines up); columns are every RESULT_DTYPE field,
flattened as in the ``/bench/results`` topic (a1..a3, g12.., v1..). Values compare
exactly, NaN equal to NaN: "no differences" means the CSVs are identical.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bench.mcaplog.schemas import RESULT_COLUMNS, Column


@dataclass(slots=True)
class ColumnDiff:
    name: str
    rows: int  # matched rows where this column differs
    max_abs: float | None  # largest |recorded - recomputed| over finite pairs (numbers only)
    examples: list[tuple[int, float, float]] = field(
        default_factory=list
    )  # (n, recorded, recomputed)


@dataclass(slots=True)
class CompareReport:
    recorded_rows: int
    recomputed_rows: int
    matched_rows: int
    only_recorded: int  # n present in the recording only
    only_recomputed: int
    rows_differing: int  # matched rows with at least one differing column
    columns: list[ColumnDiff]
    first_rows: list[tuple[int, list[str]]]  # (n, differing columns) of the first rows
    aligned_by: str = "n"
    only_recorded_n: list[int] = field(default_factory=list)
    only_recomputed_n: list[int] = field(default_factory=list)

    @property
    def identical(self) -> bool:
        return (
            self.rows_differing == 0
            and self.only_recorded == 0
            and self.only_recomputed == 0
            and self.recorded_rows == self.recomputed_rows
        )

    def as_dict(self) -> dict[str, object]:
        return {
            "identical": self.identical,
            "recorded_rows": self.recorded_rows,
            "recomputed_rows": self.recomputed_rows,
            "matched_rows": self.matched_rows,
            "only_recorded": self.only_recorded,
            "only_recomputed": self.only_recomputed,
            "rows_differing": self.rows_differing,
            "columns": {
                c.name: {"rows": c.rows, "max_abs": c.max_abs, "examples": c.examples}
                for c in self.columns
            },
            "first_rows": self.first_rows,
            "aligned_by": self.aligned_by,
        }

    def format(self) -> str:
        if self.identical:
            return f"compare: identical ({self.matched_rows} rows match the recording exactly)"
        out = [
            f"compare: DIFFERENT - {self.rows_differing} of {self.matched_rows} matched rows "
            f"differ; recorded {self.recorded_rows} rows, recomputed {self.recomputed_rows} "
            f"(aligned by {self.aligned_by})"
        ]
        if self.only_recorded:
            first = self.only_recorded_n
            out.append(f"  {self.only_recorded} rows only in the recording (first n: {first})")
        if self.only_recomputed:
            first = self.only_recomputed_n
            out.append(f"  {self.only_recomputed} rows only in the replay (first n: {first})")
        for c in self.columns:
            mx = f", max |diff| {c.max_abs:.6g}" if c.max_abs is not None else ""
            ex = "; ".join(f"n {n}: {a!r} -> {b!r}" for n, a, b in c.examples)
            out.append(f"  {c.name:<16} {c.rows} rows{mx}  e.g. {ex}")
        for n, cols in self.first_rows:
            out.append(f"  first differing row n {n}: {', '.join(cols)}")
        return "\n".join(out)


def _differs(col: Column, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    va, vb = col.values(a), col.values(b)
    if col.kind == "float":
        return ~((va == vb) | (np.isnan(va) & np.isnan(vb)))
    return va != vb


def _align(recorded: np.ndarray, recomputed: np.ndarray) -> tuple[np.ndarray, np.ndarray, str]:
    na, nb = recorded["n"], recomputed["n"]
    if len(np.unique(na)) == len(na) and len(np.unique(nb)) == len(nb):
        _, ia, ib = np.intersect1d(na, nb, assume_unique=True, return_indices=True)
        return ia, ib, "n"
    k = min(len(recorded), len(recomputed))
    return np.arange(k), np.arange(k), "row position"


def compare_results(
    recorded: np.ndarray, recomputed: np.ndarray, *, max_examples: int = 3
) -> CompareReport:
    """Compare two RESULT_DTYPE arrays (recorded in the MCAP, recomputed by replay)."""
    ia, ib, how = _align(recorded, recomputed)
    a, b = recorded[ia], recomputed[ib]
    any_diff = np.zeros(len(a), dtype=bool)
    columns: list[ColumnDiff] = []
    per_col: list[tuple[str, np.ndarray]] = []
    for col in RESULT_COLUMNS:
        diff = _differs(col, a, b)
        if not diff.any():
            continue
        any_diff |= diff
        per_col.append((col.name, diff))
        va, vb = col.values(a)[diff], col.values(b)[diff]
        max_abs = None
        if col.kind != "bool":
            d = np.abs(va.astype(np.float64) - vb.astype(np.float64))
            d = d[np.isfinite(d)]
            max_abs = float(d.max()) if len(d) else None
        idx = np.flatnonzero(diff)[:max_examples]
        examples = [(int(a["n"][i]), col.values(a)[i].item(), col.values(b)[i].item()) for i in idx]
        columns.append(ColumnDiff(col.name, int(np.count_nonzero(diff)), max_abs, examples))
    first_rows = [
        (int(a["n"][i]), [name for name, d in per_col if d[i]])
        for i in np.flatnonzero(any_diff)[:max_examples]
    ]
    only_a = np.setdiff1d(np.arange(len(recorded)), ia)
    only_b = np.setdiff1d(np.arange(len(recomputed)), ib)
    return CompareReport(
        recorded_rows=len(recorded),
        recomputed_rows=len(recomputed),
        matched_rows=len(a),
        only_recorded=len(only_a),
        only_recomputed=len(only_b),
        rows_differing=int(np.count_nonzero(any_diff)),
        columns=columns,
        first_rows=first_rows,
        aligned_by=how,
        only_recorded_n=recorded["n"][only_a[:max_examples]].tolist(),
        only_recomputed_n=recomputed["n"][only_b[:max_examples]].tolist(),
    )
