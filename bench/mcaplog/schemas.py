"""Topics, schemas and message encodings of the bench's MCAP files (docs/MCAP.md is the spec).

Raw frames use a fixed-size protobuf encoding: every message on ``/can/frames`` is the same
38 bytes, laid out as a numpy struct, so the writer builds a whole chunk of frame records
with one array assignment and the reader gathers them back with one fancy index, while
Foxglove (protobufjs) still decodes them with the schema below. Everything derived is JSON
with a jsonschema whose root is ``"type": "object"`` and whose leaves have one scalar type,
which is what Foxglove's JSON-schema parser accepts and what its Plot panel plots.

JSON floats are written with ``repr`` (shortest round-trip text), so a reader gets the
identical float64 back; NaN is written as ``null`` and +/-inf as ``1e999``/``-1e999``.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bench.records.board import SPEED_DTYPE, STATUS_DTYPE
from bench.records.model import MODEL_DTYPE
from bench.records.results import RESULT_DTYPE
from bench.records.samples import SAMPLE_DTYPE
from protocol.layout import BoardState, Outcome

# -- topics --------------------------------------------------------------------------------
FRAME_TOPIC = "/can/frames"
LINK_ERROR_TOPIC = "/uart/link_errors"
NOTICE_TOPIC = "/source/notices"
SAMPLE_TOPIC = "/bench/samples"
RESULT_TOPIC = "/bench/results"
STATUS_TOPIC = "/bench/status"
SPEED_TOPIC = "/bench/speed"
HEALTH_TOPIC = "/bench/health"
EVENT_TOPIC = "/bench/events"
TRUTH_TOPIC = "/emulator/truth"
MODEL_TOPIC = "/bench/model"

PROFILE = ""
"""MCAP header profile: none of the well-known ones applies (documented in docs/MCAP.md)."""
FORMAT_VERSION = "1"
"""Version of the bench's MCAP content layout, stored in the ``bench`` metadata record."""

# -- raw frames: fixed-size protobuf ------------------------------------------------------
FRAME_SCHEMA_NAME = "acb3.bench.RawFrame"

FRAME_PB_DTYPE = np.dtype(
    [
        ("tag_t", "u1"),  # 0x09: field 1, wire type 1 (64-bit)
        ("t", "<f8"),  # receive time, s (NaN when the medium carries none)
        ("tag_id", "u1"),  # 0x15: field 2, wire type 5 (32-bit)
        ("id", "<u4"),
        ("tag_dlc", "u1"),  # 0x1D: field 3, fixed32
        ("dlc", "<u4"),
        ("tag_flags", "u1"),  # 0x25: field 4, fixed32
        ("flags", "<u4"),
        ("tag_outcome", "u1"),  # 0x28: field 5, varint (enum value < 128: always 1 byte)
        ("outcome", "u1"),
        ("tag_uart", "u1"),  # 0x30: field 6, varint (bool: 1 byte)
        ("uart", "u1"),
        ("tag_data", "u1"),  # 0x3A: field 7, length-delimited
        ("len_data", "u1"),  # always 8: payload zero padded, dlc says how much is real
        ("data", "u1", (8,)),
    ]
)
"""One ``/can/frames`` message payload: valid protobuf wire format with a fixed layout."""

FRAME_PB_CONST = {
    "tag_t": 0x09,
    "tag_id": 0x15,
    "tag_dlc": 0x1D,
    "tag_flags": 0x25,
    "tag_outcome": 0x28,
    "tag_uart": 0x30,
    "tag_data": 0x3A,
    "len_data": 8,
}

FLAG_BATCH_START = 0x100
"""Bit 8 of the stored ``flags`` (above protocol.records' FLAG_* byte): this frame opened a
source batch of the live run (one pipeline step). Readers strip it from FRAME_DTYPE flags."""

MESSAGE_OPCODE = 0x05
MESSAGE_HEADER = [
    ("opcode", "u1"),
    ("length", "<u8"),
    ("channel_id", "<u2"),
    ("sequence", "<u4"),
    ("log_time", "<u8"),
    ("publish_time", "<u8"),
]
MESSAGE_HEADER_SIZE = 31
"""opcode + record length + channel id + sequence + log time + publish time."""
FRAME_RECORD_DTYPE = np.dtype([*MESSAGE_HEADER, ("payload", FRAME_PB_DTYPE)])
"""A complete MCAP Message record carrying one raw frame (69 bytes)."""
FRAME_RECORD_LENGTH = FRAME_RECORD_DTYPE.itemsize - 9
"""The record's content length field (everything after opcode and length)."""

assert FRAME_PB_DTYPE.itemsize == 38 and FRAME_RECORD_DTYPE.itemsize == 69


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        out.append(b | (0x80 if n else 0))
        if not n:
            return bytes(out)


def _key(field: int, wire: int) -> bytes:
    return _varint(field << 3 | wire)


def _ld(field: int, payload: bytes) -> bytes:
    return _key(field, 2) + _varint(len(payload)) + payload


def _pstr(field: int, text: str) -> bytes:
    return _ld(field, text.encode())


def _pint(field: int, value: int) -> bytes:
    return _key(field, 0) + _varint(value)


_TYPE_DOUBLE, _TYPE_FIXED32, _TYPE_BOOL, _TYPE_BYTES, _TYPE_ENUM = 1, 7, 8, 12, 14
_LABEL_OPTIONAL = 1


def _pb_field(name: str, number: int, ftype: int, type_name: str = "") -> bytes:
    """A google.protobuf.FieldDescriptorProto."""
    body = _pstr(1, name) + _pint(3, number) + _pint(4, _LABEL_OPTIONAL) + _pint(5, ftype)
    if type_name:
        body += _pstr(6, type_name)
    return body + _pstr(10, name)  # json_name


def _frame_descriptor_set() -> bytes:
    """google.protobuf.FileDescriptorSet of ``acb3/bench/raw_frame.proto``, hand encoded
    (no protobuf dependency). Equivalent source::

        syntax = "proto3";
        package acb3.bench;
        message RawFrame {
          enum Outcome { OK = 0; UNKNOWN_ID = 1; WRONG_DLC = 2; CRC_MISMATCH = 3;
                         COBS_ERROR = 4; CRC16_ERROR = 5; LENGTH_ERROR = 6; }
          double t = 1; fixed32 id = 2; fixed32 dlc = 3; fixed32 flags = 4;
          Outcome outcome = 5; bool uart = 6; bytes data = 7;
        }
    """
    enum = _pstr(1, "Outcome") + b"".join(
        _ld(2, _pstr(1, o.name) + _pint(2, int(o))) for o in Outcome
    )
    fields = [
        _pb_field("t", 1, _TYPE_DOUBLE),
        _pb_field("id", 2, _TYPE_FIXED32),
        _pb_field("dlc", 3, _TYPE_FIXED32),
        _pb_field("flags", 4, _TYPE_FIXED32),
        _pb_field("outcome", 5, _TYPE_ENUM, ".acb3.bench.RawFrame.Outcome"),
        _pb_field("uart", 6, _TYPE_BOOL),
        _pb_field("data", 7, _TYPE_BYTES),
    ]
    message = _pstr(1, "RawFrame") + b"".join(_ld(2, f) for f in fields) + _ld(4, enum)
    file = (
        _pstr(1, "acb3/bench/raw_frame.proto")
        + _pstr(2, "acb3.bench")
        + _ld(4, message)
        + _pstr(12, "proto3")
    )
    return _ld(1, file)


FRAME_SCHEMA_DATA = _frame_descriptor_set()


# -- JSON columns --------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Column:
    """One JSON property taken from a structured-array field (element ``index`` of a
    sub-array field, or the whole scalar field when index is None)."""

    name: str
    field: str
    index: int | None
    kind: str  # "int", "float", "bool"
    description: str = ""

    def values(self, rows: np.ndarray) -> np.ndarray:
        col = rows[self.field]
        return col[:, self.index] if self.index is not None else col


_KIND = {"b": "bool", "i": "int", "u": "int", "f": "float"}

_SUBARRAY_NAMES: dict[str, Sequence[str]] = {
    "acc": ("a1", "a2", "a3"),
    "slopes": ("g12", "g23", "g13"),
    "votes": ("v1", "v2", "v3"),
    "weights": ("w12", "w23", "w13"),
    "code": ("code1", "code2", "code3"),
    "status": ("status1", "status2", "status3"),
    "present": ("present1", "present2", "present3"),
}

_DESCRIPTIONS = {
    "n": "unwrapped sample index (the CSV 'counter' column)",
    "seq": "arrival index of the frame (whole run)",
    "ticks": "unwrapped board time, 100 us ticks",
    "t": "receive time, s (POSIX for live runs); null = NaN",
    "time_s": "board time since the first sample, s",
    "gradient": "reference method result, per mille; null = NaN (invalid)",
    "valid": "reference gradient valid (at least one vote passed)",
    "gradient_signed": "estimator (joint filter) gradient, per mille; null = withheld",
    "gradient_ls": "least-squares magnitude, per mille",
    "u": "specific force along the track, m/s^2",
    "w": "specific force normal to the track, m/s^2",
    "a_ref": "reference acceleration from SPEED_REF, m/s^2; null = unavailable",
    "residual": "least-squares residual, m/s^2",
    "degraded": "computed from two channels only",
    "excluded": "channel excluded by the estimator (1..3), 0 = none",
    "gradient_sigma": "1-sigma of the estimator gradient, per mille (given even when withheld)",
    "odometer_suspect": "SPEED_REF rejected by the filter's innovation gate (slip or slide)",
    "coasting": "no SPEED_REF for coast_s: the filter runs on the accelerometers alone",
}


def columns_for(dtype: np.dtype, names: dict[str, Sequence[str]] | None = None) -> list[Column]:
    """Flatten a structured dtype into JSON columns: sub-array fields become one column per
    element (``acc`` -> ``a1, a2, a3``; unknown ones ``x`` -> ``x1, x2, ...``)."""
    names = {**_SUBARRAY_NAMES, **(names or {})}
    cols: list[Column] = []
    for field in dtype.names or ():
        ftype = dtype[field]
        base = ftype.base if ftype.shape else ftype
        kind = _KIND.get(base.kind)
        if kind is None:
            continue  # strings, voids: not representable as plottable scalars
        if ftype.shape:
            count = int(np.prod(ftype.shape))
            labels = names.get(field) or [f"{field}{k + 1}" for k in range(count)]
            if len(ftype.shape) != 1 or len(labels) != count:
                labels = [f"{field}{k + 1}" for k in range(count)]
            cols += [Column(lab, field, k, kind) for k, lab in enumerate(labels)]
        else:
            cols.append(Column(field, field, None, kind, _DESCRIPTIONS.get(field, "")))
    return cols


RESULT_COLUMNS = columns_for(RESULT_DTYPE)
SAMPLE_COLUMNS = columns_for(SAMPLE_DTYPE)
STATUS_COLUMNS = columns_for(STATUS_DTYPE)
SPEED_COLUMNS = columns_for(SPEED_DTYPE)


def float_tokens(values: np.ndarray) -> list[str]:
    """repr() of each float (C loop), then the few non-finite ones patched."""
    vals = np.asarray(values, dtype=np.float64)
    out = list(map(repr, vals.tolist()))
    for i in np.flatnonzero(~np.isfinite(vals)).tolist():
        v = float(vals[i])
        out[i] = "null" if v != v else ("1e999" if v > 0 else "-1e999")
    return out


_BOOL_TOKENS = ("false", "true")


def tokens(col: Column, rows: np.ndarray) -> list[str]:
    """JSON text of one column for every row."""
    values = col.values(rows)
    if col.kind == "float":
        return float_tokens(values)
    if col.kind == "bool":
        return list(map(_BOOL_TOKENS.__getitem__, values.astype(bool).tolist()))
    return list(map(str, values.astype(np.int64).tolist()))


def encode_rows(
    rows: np.ndarray,
    columns: Sequence[Column],
    extra: Sequence[tuple[str, list[str]]] = (),
) -> list[bytes]:
    """One compact JSON object per row, built column-wise (no per-row dict or json.dumps).

    ``extra`` adds (name, already-encoded JSON tokens) columns, e.g. a state name.
    """
    if len(rows) == 0:
        return []
    names = [c.name for c in columns] + [name for name, _ in extra]
    template = "{" + ",".join(f'"{name}":%s' for name in names) + "}"
    cols = [tokens(c, rows) for c in columns] + [list(values) for _, values in extra]
    return [(template % row).encode() for row in zip(*cols, strict=True)]


def decode_rows(
    messages: Sequence[bytes | memoryview], columns: Sequence[Column], dtype: np.dtype
) -> np.ndarray:
    """The inverse of :func:`encode_rows`: JSON objects back into a structured array.

    Missing properties stay zero; null floats become NaN. Exact for floats written by
    :func:`encode_rows`.
    """
    out = np.zeros(len(messages), dtype=dtype)
    if not messages:
        return out
    objs = [json.loads(bytes(m)) for m in messages]
    for col in columns:
        if col.name not in objs[0] and not any(col.name in o for o in objs):
            continue
        if col.kind == "float":
            vals = np.array(
                [np.nan if (v := o.get(col.name)) is None else v for o in objs], dtype=np.float64
            )
        else:
            vals = np.array([o.get(col.name) or 0 for o in objs], dtype=np.int64)
        target = out[col.field]
        if col.index is not None:
            target[:, col.index] = vals
        else:
            out[col.field] = vals
    return out


def json_text(value: object) -> str:
    """A JSON token for one Python value (strings escaped; floats as in :func:`tokens`)."""
    if isinstance(value, float):
        return float_tokens(np.array([value]))[0]
    return json.dumps(value, ensure_ascii=False)


# -- jsonschemas ---------------------------------------------------------------------------
_JSON_TYPE = {"int": "integer", "float": "number", "bool": "boolean"}


def _prop(kind: str, description: str = "") -> dict[str, object]:
    prop: dict[str, object] = {"type": _JSON_TYPE.get(kind, kind)}
    if description:
        prop["description"] = description
    return prop


def object_schema(
    title: str,
    description: str,
    columns: Sequence[Column],
    extra: dict[str, dict[str, object]] | None = None,
) -> dict[str, object]:
    props = {c.name: _prop(c.kind, c.description) for c in columns}
    props.update(extra or {})
    return {"title": title, "description": description, "type": "object", "properties": props}


def result_schema(columns: Sequence[Column] = RESULT_COLUMNS) -> dict[str, object]:
    """The results' schema; ``columns`` beyond RESULT_COLUMNS: `bench replay --smooth
    --mcap`'s smoothed gradient and model estimates (bench.replay.model_columns)."""
    more = "" if columns is RESULT_COLUMNS else ", then the smoother's columns"
    return object_schema(
        "acb3.bench.Result",
        f"One fusion result per sampling instant: every RESULT_DTYPE field{more} (CSV columns "
        "included; CSV 'counter' = n). Floats round-trip exactly; null = NaN.",
        columns,
    )


RESULT_SCHEMA = result_schema()
SAMPLE_SCHEMA = object_schema(
    "acb3.bench.Sample",
    "One assembled sampling instant (SAMPLE_DTYPE): raw codes, status bytes, presence.",
    SAMPLE_COLUMNS,
)
STATUS_SCHEMA = object_schema(
    "acb3.bench.BoardStatus",
    "A valid BOARD_STATUS frame, decoded (ICD 1.2).",
    STATUS_COLUMNS,
    {
        "state_name": {"type": "string", "description": "BOOT, RUN, DEGRADED, FAULT or ?"},
        "supply_v": {"type": "number", "description": "supply voltage, V"},
    },
)
SPEED_SCHEMA = object_schema(
    "acb3.bench.SpeedRef",
    "A valid SPEED_REF frame, decoded (ICD 1.3); speed in mm/s as sent.",
    SPEED_COLUMNS,
    {"speed_mps": {"type": "number", "description": "speed, m/s"}},
)
LINK_ERROR_SCHEMA: dict[str, object] = {
    "title": "acb3.bench.LinkError",
    "description": "A UART packet that could not be turned into a frame, with its raw bytes.",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "receive time, s; null = NaN"},
        "outcome": {"type": "integer", "description": "protocol.layout.Outcome value"},
        "outcome_name": {"type": "string"},
        "raw": {"type": "string", "contentEncoding": "base64", "description": "bytes as received"},
        "length": {"type": "integer", "description": "len(raw)"},
        "detail": {"type": "string"},
    },
}
NOTICE_SCHEMA: dict[str, object] = {
    "title": "acb3.bench.SourceNotice",
    "description": "Something the source reported that is not a frame (bad log line, "
    "disconnect, reconnect, truncation, frames the kernel dropped at the socket).",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "s; null = NaN"},
        "kind": {"type": "string"},
        "detail": {"type": "string"},
        "count": {
            "type": "integer",
            "description": "overflow: frames the kernel dropped since the last notice; else 0",
        },
    },
}
HEALTH_CHANNEL_FIELDS = (
    "frames",
    "crc_errors",
    "gaps",
    "duplicates",
    "late",
    "status_flagged",
    "counter_jumps",
)
HEALTH_TOTAL_FIELDS = (
    "frames",
    "crc_errors",
    "wrong_dlc",
    "unknown_id",
    "link_errors",
    "parse_errors",
    "samples",
    "valid",
    "degraded",
    "samples_lost",
    "status_frames",
    "speed_frames",
    "dropped_frames",
    "socket_drops",
)
HEALTH_SCHEMA: dict[str, object] = {
    "title": "acb3.bench.Health",
    "description": "Running counters (bench.stats) about once per second of receive time; "
    "channels[0..2] are ch1..ch3.",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "receive time of the snapshot, s"},
        **{name: {"type": "integer"} for name in HEALTH_TOTAL_FIELDS},
        "valid_fraction": {"type": "number"},
        "channels": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "channel": {"type": "integer"},
                    "rate_hz": {"type": "number", "description": "valid frames per second"},
                    **{name: {"type": "integer"} for name in HEALTH_CHANNEL_FIELDS},
                },
            },
        },
    },
}
LOG_LEVELS = {"debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}
EVENT_SCHEMA: dict[str, object] = {
    "title": "foxglove.Log",
    "description": "A bench event as a foxglove.Log message, plus the bench.events fields "
    "(t, kind, kind_name, channel, n, value) and the operator's text for marks.",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "title": "time",
            "properties": {
                "sec": {"type": "integer", "minimum": 0},
                "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
            },
            "description": "Timestamp of log message",
        },
        "level": {
            "title": "foxglove.LogLevel",
            "description": "Log level",
            "oneOf": [
                {"title": name.upper(), "const": value}
                for name, value in {"unknown": 0, **LOG_LEVELS}.items()
            ],
        },
        "message": {"type": "string", "description": "bench.events.describe() of the event"},
        "name": {"type": "string", "description": "who raised it: bench, operator, logger"},
        "file": {"type": "string", "description": "Filename"},
        "line": {"type": "integer", "minimum": 0, "description": "Line number in the file"},
        "t": {"type": "number", "description": "event time, s; null = NaN"},
        "kind": {"type": "integer", "description": "bench.events.EventKind value"},
        "kind_name": {"type": "string"},
        "channel": {"type": "integer"},
        "n": {"type": "integer", "description": "sample index, -1 = none"},
        "value": {"type": "integer"},
        "text": {"type": "string", "description": "operator's text (marks only)"},
    },
    "required": ["timestamp", "level", "message", "name", "file", "line"],
}


def truth_schema(columns: Sequence[Column]) -> dict[str, object]:
    return object_schema(
        "acb3.bench.Truth",
        "Emulator ground truth, one message per row of the emulation's truth table.",
        columns,
    )


def schema_bytes(schema: dict[str, object]) -> bytes:
    return json.dumps(schema, indent=None, separators=(",", ":")).encode()


@dataclass(frozen=True, slots=True)
class TopicSpec:
    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str
    schema_data: bytes
    description: str


def _json_topic(topic: str, schema: dict[str, object], description: str) -> TopicSpec:
    return TopicSpec(
        topic, str(schema["title"]), "jsonschema", "json", schema_bytes(schema), description
    )


TOPICS: tuple[TopicSpec, ...] = (
    TopicSpec(
        FRAME_TOPIC,
        FRAME_SCHEMA_NAME,
        "protobuf",
        "protobuf",
        FRAME_SCHEMA_DATA,
        "every CAN/UART frame as received (valid, corrupt, unknown id), fixed 38-byte protobuf",
    ),
    _json_topic(LINK_ERROR_TOPIC, LINK_ERROR_SCHEMA, "UART packets that failed to decode"),
    _json_topic(NOTICE_TOPIC, NOTICE_SCHEMA, "source notices (disconnect, parse errors, ...)"),
    _json_topic(SAMPLE_TOPIC, SAMPLE_SCHEMA, "assembled samples"),
    _json_topic(RESULT_TOPIC, RESULT_SCHEMA, "fusion results (every CSV column)"),
    _json_topic(STATUS_TOPIC, STATUS_SCHEMA, "decoded BOARD_STATUS frames"),
    _json_topic(SPEED_TOPIC, SPEED_SCHEMA, "decoded SPEED_REF frames"),
    _json_topic(HEALTH_TOPIC, HEALTH_SCHEMA, "per-channel health, about 1 Hz"),
    _json_topic(EVENT_TOPIC, EVENT_SCHEMA, "events and operator marks (foxglove.Log)"),
)


def result_topic(columns: Sequence[Column]) -> TopicSpec:
    """The results' topic with the given columns (:func:`result_schema`)."""
    return _json_topic(RESULT_TOPIC, result_schema(columns), "fusion results (every CSV column)")


MODEL_COLUMNS = columns_for(
    MODEL_DTYPE, {"bias": ["b1", "b2", "b3"], "bias_sigma": ["b1_sigma", "b2_sigma", "b3_sigma"]}
)
MODEL_SCHEMA = object_schema(
    "acb3.bench.Model",
    "The explicit model of a live run (--lag), one message per block (BLOCK_S): the filter's "
    "gradient, wheel-diameter error E (1), body-pitch compliance C (deg per m/s^2) and channel "
    "biases b1-b3 (m/s^2), each with its 1-sigma, and the gradient fixed-lag smoothed with "
    "lag_s of samples after the block. Floats round-trip exactly; null = NaN.",
    MODEL_COLUMNS,
)
MODEL_TOPIC_SPEC = _json_topic(
    MODEL_TOPIC, MODEL_SCHEMA, "the explicit model's live estimates (--lag), per block"
)
"""Only in a log whose run had the model: added with its first message."""


def truth_topic(columns: Sequence[Column]) -> TopicSpec:
    return _json_topic(TRUTH_TOPIC, truth_schema(columns), "emulator ground truth")


def state_name(state: int) -> str:
    return BoardState(state).name if state in BoardState._value2member_map_ else "?"


def outcome_name(value: int) -> str:
    return Outcome(value).name if value in Outcome._value2member_map_ else str(value)
