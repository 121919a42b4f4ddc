"""Acceptance plans (TOML): load, resolve and validate strictly.

A plan is a scenario for the virtual board (embedded as a ``[scenario]`` table in the
emulator's own format, or ``scenario = "name-or-path"``), operator steps for a real board
(``[[steps]]``), an optional calibration overlay (``[config]``) and the checks with their
limits (``[[checks]]``). Every mistake is one ConfigError line naming the file and key,
because a typo in a limit that were silently ignored would pass a device unseen.
The format is documented in docs/ACCEPTANCE.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from bench.acceptance.checks.base import CheckSpec, Param
from bench.acceptance.checks.registry import KINDS
from bench.acceptance.signoff import DUT_KEYS, Dut
from bench.config import Config, config_from_dict
from bench.errors import ConfigError
from devices.textfile import parse_toml, path_or_packaged, read_text_file
from devices.tomlcheck import Table, tname

PLAN_DIR = Path(__file__).resolve().parent.parent / "plans"
"""The plan library shipped with the bench (``bench/plans/*.toml``)."""

EXPECTS = ("pass", "fail")
CHECK_EXPECTS = ("pass", "warn", "fail", "skip")
LINKS = ("can", "uart")
_TOP = ("plan", "scenario", "config", "steps", "checks")
_PLAN_KEYS = ("name", "title", "expect", "link", "duration_s", "dut")
_STEP_KEYS = ("prompt", "gradient_permil", "settle_s", "measure_s", "at_s")
_CHECK_COMMON = ("name", "kind", "from_s", "to_s", "expect", "requirement")


@dataclass(frozen=True, slots=True)
class Step:
    """An operator step: set something up, confirm, let it settle, measure."""

    index: int  # 1-based
    prompt: str
    gradient_permil: float  # what the bench should then read
    settle_s: float = 2.0
    measure_s: float = 5.0
    at_s: float | None = None  # not before this run time (a motorised table's programme)


@dataclass(frozen=True)
class Plan:
    name: str
    title: str
    expect: str  # the verdict this plan is meant to give against a healthy bench
    path: Path | None
    text: str  # the plan file as written, for the record
    checks: tuple[CheckSpec, ...]
    steps: tuple[Step, ...] = ()
    scenario: Any = None  # devices.emulator.Scenario, or None for a board-only plan
    scenario_data: dict[str, Any] | None = None  # the scenario as parsed TOML
    scenario_ref: str | None = None  # the referenced scenario file, if not embedded
    config_overlay: dict[str, Any] = field(default_factory=dict)
    link: str = "can"
    duration_s: float | None = None
    file: str = "<plan>"  # how error messages name the plan file
    dut: Dut = field(default_factory=Dut)  # [plan] dut: the unit this plan is run on
    requirements: dict[str, tuple[str, ...]] = field(default_factory=dict)  # check name -> IDs

    def requirement_ids(self, check: str) -> tuple[str, ...]:
        """The requirement IDs a check verifies (``requirement`` in its [[checks]] table)."""
        return self.requirements.get(check, ())

    @property
    def emulated(self) -> bool:
        return self.scenario is not None

    def config(self) -> Config:
        """The calibration for an emulated run: the virtual board as built (true angles,
        sample rate, base id), with the plan's [config] overlay on top."""
        return build_config(
            self.scenario, self.config_overlay, self.file, f"scenario of plan {self.name}"
        )

    def scenario_toml(self) -> str:
        """The scenario as a TOML file the emulator reads back to the same Scenario."""
        return dump_toml(self.scenario_data or {})


# --------------------------------------------------------------------------- helpers


def _param(t: Table, key: str, p: Param) -> Any:
    if p.type == "number":
        return t.num(key, lo=p.lo, hi=p.hi)
    if p.type == "integer":
        return t.integer(key, lo=p.lo, hi=p.hi)
    if p.type == "bool":
        return t.flag(key)
    if p.type == "choice":
        return t.choice(key, choices=p.choices)
    if p.type == "events":
        v = t.raw(key)
        items = [v] if isinstance(v, str) else v
        if not isinstance(items, list) or not items:
            raise t.error(key, f"expected a non-empty array of event names, got {v!r}")
        for item in items:
            if not isinstance(item, str) or item.upper() not in p.choices:
                raise t.error(
                    key, f"unknown event {item!r} (expected names from {', '.join(p.choices)})"
                )
        return tuple(dict.fromkeys(i.upper() for i in items))
    return t.text(key)  # pragma: no cover - every Param type is handled above


# --------------------------------------------------------------------------- sections


def _steps(top: Table) -> tuple[Step, ...]:
    out = []
    for i, item in enumerate(top.array("steps"), 1):
        t = Table(top.file, f"steps[{i}]", item)
        t.done(_STEP_KEYS)
        for key in ("prompt", "gradient_permil"):
            t.require(key, "every step needs it")
        out.append(
            Step(
                index=i,
                prompt=t.text("prompt"),
                gradient_permil=t.num("gradient_permil", lo=-500, hi=500),
                settle_s=t.num("settle_s", 2.0, 0.0, 3600.0),
                measure_s=t.num("measure_s", 5.0, 0.0, 3600.0, lo_open=True),
                at_s=t.num("at_s", lo=0.0) if t.has("at_s") else None,
            )
        )
    return tuple(out)


def _checks(top: Table) -> tuple[CheckSpec, ...]:
    items = top.raw("checks")
    if not isinstance(items, list) or not items:
        raise top.error("checks", "a plan needs at least one [[checks]] table")
    out = []
    names: dict[str, int] = {}
    for i, item in enumerate(items, 1):
        t = Table(top.file, f"checks[{i}]", item)
        t.require("kind", f"one of {', '.join(KINDS)}")
        kind = t.raw("kind")
        if not isinstance(kind, str) or kind not in KINDS:
            raise t.error(
                "kind", f"unknown check kind {kind!r} (expected one of {', '.join(KINDS)})"
            )
        spec = KINDS[kind]
        t.done((*_CHECK_COMMON, *spec.params))
        params: dict[str, Any] = {}
        for key, p in spec.params.items():
            if t.has(key):
                params[key] = _param(t, key, p)
            elif p.required:
                raise t.error(key, f"missing (a {kind} check needs it)")
        lim = spec.limit
        limit = params.get(lim.key, spec.params[lim.key].default) if lim.key else None
        if lim.warn_key and lim.warn_key in params and limit is not None:
            warn = params[lim.warn_key]
            if (warn > limit) if lim.upper else (warn < limit):
                rel = "<=" if lim.upper else ">="
                raise t.error(
                    lim.warn_key,
                    f"the warning limit must be {rel} {lim.key} ({limit!r}), got {warn!r}",
                )
        name = t.text("name", f"{kind} #{i}").strip()
        if not name:
            raise t.error("name", "must not be empty")
        if name in names:
            raise t.error("name", f"{name!r} is already the name of checks[{names[name]}]")
        names[name] = i
        from_s = t.num("from_s", lo=0.0) if t.has("from_s") else None
        to_s = t.num("to_s", lo=0.0, lo_open=True) if t.has("to_s") else None
        if from_s is not None and to_s is not None and to_s <= from_s:
            raise t.error("to_s", f"must be > from_s ({from_s:g}), got {to_s!r}")
        expect = t.choice("expect", choices=CHECK_EXPECTS) if t.has("expect") else None
        out.append(CheckSpec(i, name, kind, params, from_s, to_s, expect))
    return tuple(out)


def _requirements(top: Table, checks: tuple[CheckSpec, ...]) -> dict[str, tuple[str, ...]]:
    """``requirement = "REQ-GRD-012"`` (or an array of IDs) per check, by check name."""
    out = {}
    for c, item in zip(checks, top.raw("checks"), strict=True):
        if "requirement" not in item:
            continue
        t = Table(top.file, f"checks[{c.index}]", item)
        v = t.raw("requirement")
        ids = [v] if isinstance(v, str) else v
        if not isinstance(ids, list) or not ids:
            raise t.error("requirement", f"expected an ID or an array of IDs, got {v!r}")
        for rid in ids:
            if not isinstance(rid, str) or not rid.strip() or any(ch.isspace() for ch in rid):
                raise t.error("requirement", f"expected IDs without spaces, got {rid!r}")
        out[c.name] = tuple(dict.fromkeys(ids))
    return out


def _dut(head: Table) -> Dut:
    if not head.has("dut"):
        return Dut()
    t = Table(head.file, "plan.dut", head.raw("dut"))  # not a table: one line naming it
    t.done(DUT_KEYS)
    return Dut(**{k: t.text(k).strip() or None for k in DUT_KEYS if t.has(k)})


def _cross_checks(top: Table, plan: Plan) -> None:
    """What only the whole plan can tell: a check that needs truth, steps or a fault."""
    sc = plan.scenario
    for c in plan.checks:
        where = f"checks[{c.index}]"
        kind = KINDS[c.kind]
        if kind.needs_truth and sc is None:
            raise top.error(
                f"{where}.kind", f"a {c.kind} check needs emulator truth: the plan has no scenario"
            )
        if kind.needs_steps and not plan.steps:
            raise top.error(f"{where}.kind", f"a {c.kind} check needs [[steps]]: the plan has none")
        if sc is not None and c.from_s is not None and c.from_s >= sc.duration_s:
            raise top.error(
                f"{where}.from_s", f"must be < the scenario's duration_s ({sc.duration_s:g})"
            )
        if (
            c.kind == "step_gradient"
            and c.get("step") is not None
            and c.get("step") > len(plan.steps)
        ):
            raise top.error(f"{where}.step", f"the plan has {len(plan.steps)} steps")
        if c.kind == "fault_detected":
            _check_fault_target(top, where, c, sc)


def _check_fault_target(top: Table, where: str, c: CheckSpec, sc: Any) -> None:
    from devices.emulator.faults import target_channels

    index, channel = c.get("fault"), c.get("channel")
    faults = list(sc.faults)
    if index is not None:
        if index > len(faults):
            raise top.error(f"{where}.fault", f"the scenario has {len(faults)} [[faults]]")
        faults = [faults[index - 1]]
    chans = [set(target_channels(f)) for f in faults]
    if channel is not None and not any(channel in s for s in chans):
        raise top.error(f"{where}.channel", f"no scenario fault targets channel {channel}")
    if not any(chans):
        raise top.error(f"{where}.kind", "no scenario fault targets an ADC channel to detect")


def build_config(
    scenario: Any, overlay: dict[str, Any], source: str, board: str = "the plan's scenario"
) -> Config:
    """Scenario calibration (or nominal) with the plan's [config] tables merged on top;
    ``board`` names the emulated board in the calibration's description."""
    import tomllib as _toml

    base: dict[str, Any] = {}
    if scenario is not None:
        from devices.emulator import calibration_toml

        base = _toml.loads(calibration_toml(scenario))
    merged = dict(base)
    for key, value in overlay.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = {**merged[key], **value}
        else:
            merged[key] = value
    config = config_from_dict(merged, source=f"{source}: config")  # errors name the plan
    start = f"{board} as built" if scenario is not None else "nominal ICD values"
    if overlay:
        return replace(config, source=f"{start} + [config] of {source}", origin="plan")
    if scenario is None:
        return Config()
    return replace(config, source=start, origin="scenario")


def _scenario(top: Table, value: Any, plan_dir: Path | None) -> tuple[Any, dict | None, str | None]:
    from devices.emulator import load_scenario, scenario_from_dict
    from devices.emulator.scenario import resolve_scenario_path

    if isinstance(value, dict):
        return scenario_from_dict(value, source=f"{top.file}: scenario"), value, None
    if isinstance(value, str):
        p = Path(value)
        if plan_dir is not None and not p.is_absolute() and (plan_dir / p).exists():
            p = plan_dir / p
        try:
            path = resolve_scenario_path(p)
        except ConfigError as exc:
            raise top.error("scenario", str(exc)) from None
        sc = load_scenario(path)
        return sc, parse_toml(read_text_file(path, "scenario"), str(path)), str(path)
    raise top.error("scenario", f"expected a [scenario] table or a file name, got {tname(value)}")


# --------------------------------------------------------------------------- entry points


def parse_plan(text: str, file: str = "<plan>", path: Path | None = None) -> Plan:
    """Validate plan TOML text into a Plan; ConfigError naming ``file`` and the key."""
    data = parse_toml(text, file)
    top = Table(file, "", data)
    top.done(_TOP)
    if not top.has("plan"):
        raise top.error("plan", 'missing [plan] table (it states at least expect = "pass"|"fail")')
    head = Table(file, "plan", data["plan"])
    head.done(_PLAN_KEYS)
    head.require("expect", '"pass" or "fail": the verdict this plan is for')
    default_name = path.stem if path is not None else "plan"
    scenario, sc_data, sc_ref = (None, None, None)
    if top.has("scenario"):
        scenario, sc_data, sc_ref = _scenario(top, data["scenario"], path.parent if path else None)
    overlay = Table(file, "config", data.get("config", {}))
    overlay.done(("board", "channels", "fusion", "estimator"))
    checks = _checks(top)
    plan = Plan(
        name=head.text("name", default_name),
        title=head.text("title", ""),
        expect=head.choice("expect", choices=EXPECTS),
        path=path,
        text=text,
        checks=checks,
        steps=_steps(top),
        scenario=scenario,
        scenario_data=sc_data,
        scenario_ref=sc_ref,
        config_overlay=overlay.data,
        link=head.choice("link", "can", choices=LINKS),
        duration_s=head.num("duration_s", lo=0.0, lo_open=True) if head.has("duration_s") else None,
        file=file,
        dut=_dut(head),
        requirements=_requirements(top, checks),
    )
    if scenario is None and not plan.steps and plan.duration_s is None:
        raise top.error(
            "plan", "needs a [scenario], [[steps]] or plan.duration_s to know what to run"
        )
    failing = [c.name for c in plan.checks if c.expect == "fail"]
    if plan.expect == "fail" and not failing:
        raise head.error(
            "expect", '"fail", but no check says expect = "fail" (which one is meant to?)'
        )
    if plan.expect == "pass" and failing:
        raise head.error("expect", f'"pass", but check {failing[0]!r} says expect = "fail"')
    if overlay.data or scenario is not None:
        plan.config()  # validate the overlay now, naming its key
    _cross_checks(top, plan)
    return plan


def resolve_plan_path(name: str | Path) -> Path:
    """A path as given if it exists, else a shipped plan by name (``level`` -> level.toml)."""
    found = path_or_packaged(name, PLAN_DIR)
    if found is None:
        raise ConfigError(
            f"{name}: no such plan file (bench accept --list shows the shipped plans)"
        )
    return found


def load_plan(name: str | Path) -> Plan:
    """Read and validate a plan file (or a shipped plan by name)."""
    p = resolve_plan_path(name)
    return parse_plan(read_text_file(p, "plan"), p.name, p)


def shipped_plans() -> list[Path]:
    return sorted(PLAN_DIR.glob("*.toml"))


# --------------------------------------------------------------------------- TOML out


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        import json

        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"cannot write {type(v).__name__} as TOML")


def _key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() else _toml_value(k)


def dump_toml(data: dict[str, Any], prefix: str = "") -> str:
    """Parsed TOML back to text (tables and arrays of tables kept as such); enough for
    writing a plan's embedded scenario as the scenario file the emulator reads."""
    lines: list[str] = []
    nested: list[str] = []
    for k, v in data.items():
        full = f"{prefix}.{_key(k)}" if prefix else _key(k)
        if isinstance(v, dict):
            nested.append(f"[{full}]\n" + dump_toml(v, full))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            nested += [f"[[{full}]]\n" + dump_toml(x, full) for x in v]
        else:
            lines.append(f"{_key(k)} = {_toml_value(v)}")
    body = "\n".join(lines) + ("\n" if lines else "")
    return body + "".join(("\n" if i or lines else "") + n for i, n in enumerate(nested))
