"""Operator steps: answers (console, ``--yes`` or a steps file) and the run-time window each
answered step measures."""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from pathlib import Path

from bench.acceptance.model import StepWindow
from bench.acceptance.plan import Step
from bench.errors import BenchError, ConfigError
from devices.textfile import parse_toml, read_text_file


@dataclass(frozen=True, slots=True)
class Answer:
    """An operator's answer to a step: go on, skip it, or abort the run."""

    answer: str = "ok"  # ok | skip | abort
    reference_permil: float | None = None  # the reference inclinometer's reading
    note: str = ""


def parse_answer(text: str) -> Answer:
    """Console input: Enter = ok, a number = ok with that reference reading, s = skip,
    q = abort, anything else = ok with a note."""
    s = text.strip()
    if not s:
        return Answer()
    low = s.lower()
    if low in ("s", "skip"):
        return Answer("skip")
    if low in ("q", "quit", "abort"):
        return Answer("abort")
    with contextlib.suppress(ValueError):
        v = float(s)
        if math.isfinite(v):
            return Answer(reference_permil=v)
    return Answer(note=s)


def load_answers(path: str | Path) -> list[Answer]:
    """A steps file: ``[[answers]]`` in step order with ``answer`` ("ok" | "skip" |
    "abort"), optional ``reference_permil`` and ``note``. ConfigError naming the key."""
    p = Path(path)
    data = parse_toml(read_text_file(p, "steps file"), str(p))
    for key in data:
        if key != "answers":
            raise ConfigError(f"{p.name}: {key}: unknown key (expected: answers)")
    items = data.get("answers", [])
    if not isinstance(items, list):
        raise ConfigError(f"{p.name}: answers: expected an array of tables ([[answers]])")
    out = []
    for i, item in enumerate(items, 1):
        where = f"{p.name}: answers[{i}]"
        if not isinstance(item, dict):
            raise ConfigError(f"{where}: expected a table")
        for key in item:
            if key not in ("answer", "reference_permil", "note"):
                raise ConfigError(
                    f"{where}.{key}: unknown key (expected one of: answer, note, reference_permil)"
                )
        ans = item.get("answer", "ok")
        if ans not in ("ok", "skip", "abort"):
            raise ConfigError(f"{where}.answer: {ans!r} is not one of 'ok', 'skip', 'abort'")
        ref = item.get("reference_permil")
        if ref is not None and (
            isinstance(ref, bool) or not isinstance(ref, int | float) or not math.isfinite(ref)
        ):
            raise ConfigError(f"{where}.reference_permil: expected a number, got {ref!r}")
        note = item.get("note", "")
        if not isinstance(note, str):
            raise ConfigError(f"{where}.note: expected a string, got {note!r}")
        out.append(Answer(ans, None if ref is None else float(ref), note))
    return out


def schedule_steps(
    steps: tuple[Step, ...], answers: list[Answer] | None, begin_s: float = 0.0
) -> tuple[StepWindow, ...]:
    """Windows of steps answered at once (emulated runs): each starts at its at_s or when
    the previous one ended, whichever is later."""
    out = []
    t = begin_s
    for s in steps:
        a = answer_for(s, answers)
        if a.answer == "abort":
            raise BenchError(f"step {s.index} aborted by the steps file")
        start = max(t, s.at_s or 0.0)
        out.append(step_window(s, a, start))
        t = start + (0.0 if a.answer == "skip" else s.settle_s + s.measure_s)
    return tuple(out)


def answer_for(step: Step, answers: list[Answer] | None) -> Answer:
    if answers is None:
        return Answer()
    if step.index > len(answers):
        raise BenchError(
            f"the steps file answers {len(answers)} steps, the plan has step {step.index}"
        )
    return answers[step.index - 1]


def step_window(step: Step, a: Answer, start: float) -> StepWindow:
    expected = step.gradient_permil if a.reference_permil is None else a.reference_permil
    frm = start + step.settle_s
    return StepWindow(
        step.index, step.prompt, expected, start, frm, frm + step.measure_s, a.answer, a.note
    )
