"""How a message dataclass's fields travel in its protobuf schema: declared once per class, not copied.

A message type is a dataclass naming its schema (``class Blob(Message, schema="vgr.v1.Blob")``).
Each dataclass field travels in the protobuf field of the same name, encoded as its annotation and
that field's type say (scalars copied, ``stamp_ns`` as a Timestamp, 4x4 arrays as poses, arrays and
lists on repeated fields, dicts as named entries or JSON, message lists by their own mapping, one
bytes or array field as ``BULK``: the table is in docs/messages.md). The class variable ``WIRE``
(merged along the bases) says what name and type cannot: another protobuf name, ``None`` (not on
the wire), or a :class:`Wire` with options. ``stamp_ns`` and ``frame_id`` travel where the schema
has their fields; ``seq`` never does.

From the fields, ``WIRE`` and the schema's descriptor, :func:`codec_of` writes the class's
``to_proto`` / ``from_proto`` as Python source once, on first use (as ``dataclasses`` writes
``__init__``), so a message costs what hand-written copying cost; :func:`wire_source` shows it. A
class with a genuinely special encoding writes its own; it may call ``super()`` for the generated one.

Also here: the helpers that hand-written encodings share (stamps, poses, array bytes, JSON).
"""

from __future__ import annotations

import json
import linecache
import types
from collections.abc import Callable
from dataclasses import MISSING, dataclass, fields
from typing import Any, NamedTuple, TypeAlias, Union, get_args, get_origin, get_type_hints

import numpy as np
from google.protobuf.descriptor import FieldDescriptor

from engine import transforms as tf
from engine.messages.schemas import _is_repeated, proto_class

Bulk = memoryview | bytes | None


# --------------------------------------------------------------------------- proto helpers
# Public: hand-written encodings (and plugins' own message types) use them too.


def set_stamp(pb: Any, stamp_ns: int) -> None:
    ts = pb.timestamp  # (each attribute access of a sub-message builds a new wrapper)
    ts.seconds, ts.nanos = divmod(int(stamp_ns), 1_000_000_000)


def get_stamp(pb: Any) -> int:
    ts = pb.timestamp
    return ts.seconds * 1_000_000_000 + ts.nanos  # (protobuf integer fields read as int)


def set_pose(pose_pb: Any, T: np.ndarray) -> None:
    set_pose_parts(pose_pb.position, pose_pb.orientation, T)


def set_pose_parts(position_pb: Any, orientation_pb: Any, T: np.ndarray) -> None:
    """4x4 *T* into a Vector3 (or Point) and a Quaternion (foxglove.Pose, foxglove.FrameTransform)."""
    T = np.asarray(T, dtype=float)
    p, q = T[:3, 3], tf.quat_xyzw_from_R(T[:3, :3])
    position_pb.x, position_pb.y, position_pb.z = (float(v) for v in p)
    o = orientation_pb
    o.x, o.y, o.z, o.w = (float(v) for v in q)


def get_pose(pose_pb: Any) -> np.ndarray:
    return pose_from_parts(pose_pb.position, pose_pb.orientation)


QUAT_NORM_TOL = 1e-3  # float32 senders normalise to ~1e-7; anything further off is not a rotation


def pose_from_parts(p: Any, o: Any) -> np.ndarray:
    """4x4 from a Vector3 and a Quaternion. A quaternion that is not of unit length (an unset, all
    zero one in particular) is refused: taking it for the identity would turn a sender's missing
    orientation into a real one, and a robot would move to it."""
    q = np.array([o.x, o.y, o.z, o.w], dtype=float)
    n = float(np.linalg.norm(q))
    if not abs(n - 1.0) <= QUAT_NORM_TOL:
        raise ValueError(f"orientation quaternion {q.tolist()} is not a rotation (norm {n:.6g}, not 1): unset?")
    return tf.T_from_pose7((p.x, p.y, p.z), q)


def _bytes_of(arr: np.ndarray) -> memoryview:
    """Flat uint8 view of a C-contiguous array (copies only when the array is not contiguous)."""
    return memoryview(np.ascontiguousarray(arr).reshape(-1).view(np.uint8))


def json_default(o: Any) -> Any:
    """JSON of what json cannot write itself: numpy arrays as lists, numpy scalars as numbers."""
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    return str(o)


# --------------------------------------------------------------------------- declaration


@dataclass(frozen=True)
class Wire:
    """How one dataclass field travels, where its name and annotation do not say it all."""

    name: str | None = None  # the protobuf field (default: the dataclass field's name)
    shape: tuple[int, ...] | None = None  # array on repeated double: written flat, read back in this shape
    dtype: str | None = None  # array in the bytes field BULK: its element type (shape: its shape)
    presence: str | None = None  # optional pose: the bool field telling whether it is there
    position: str | None = None  # pose on two fields (foxglove.FrameTransform): Vector3 ...
    orientation: str | None = None  # ... and Quaternion
    unset_is_default: bool = False  # the wire's unset value ("", 0) reads as the field's default


WireMap: TypeAlias = dict[str, str | Wire | None]


class MappingError(TypeError):
    """A message class whose fields cannot be mapped to its schema (raised on its first use)."""


class Codec(NamedTuple):
    """The generated code of one message class."""

    to_proto: Callable[[Any], tuple[Any, Bulk]]
    from_proto: Callable[[type, Any, Bulk], Any]  # (cls, pb, bulk)
    fill: Callable[[Any, Any], Bulk]  # (message, protobuf to fill): to_proto into a given protobuf
    source: str


# --------------------------------------------------------------------------- generation

_CODECS: dict[type, Codec] = {}
_BASE_FIELDS = ("stamp_ns", "frame_id")  # Message's own: they travel where the schema has them
_TIMESTAMP, _POSE = "google.protobuf.Timestamp", "foxglove.Pose"
_BYTES, _STRING = FieldDescriptor.TYPE_BYTES, FieldDescriptor.TYPE_STRING
_ELEMENTS = (str, float, int, bool)
_FLOATS = (FieldDescriptor.CPPTYPE_DOUBLE, FieldDescriptor.CPPTYPE_FLOAT)
_GLOBALS = {
    "_np": np,
    "_json": json,
    "_json_default": json_default,
    "_set_pose": set_pose,
    "_get_pose": get_pose,
    "_set_pose_parts": set_pose_parts,
    "_pose_from_parts": pose_from_parts,
    "_bytes_of": _bytes_of,
}


def codec_of(cls: type) -> Codec:
    """The generated code of *cls* (written on first use); its lazy to_proto/from_proto become it."""
    codec = _CODECS.get(cls)
    if codec is None:
        codec = _CODECS[cls] = _generate(cls)
        if _is_mapped(cls.__dict__.get("to_proto")):
            cls.to_proto = mapped(codec.to_proto)  # type: ignore[attr-defined]
        if _is_mapped(cls.__dict__.get("from_proto")):
            cls.from_proto = classmethod(mapped(codec.from_proto))  # type: ignore[attr-defined]
    return codec


def generate_now(cls: type) -> None:
    """Write *cls*'s generated code now if it uses any, so that a class whose fields do not fit its
    schema fails where it is registered (engine.messages.codec) rather than on its first message."""
    if _is_mapped(getattr(cls, "to_proto", None)) or _is_mapped(getattr(cls, "from_proto", None)):
        codec_of(cls)


def wire_source(cls: type) -> str:
    """The Python source generated for *cls*'s to_proto / from_proto."""
    return codec_of(cls).source


def mapped(fn: Any) -> Any:
    """Mark *fn* as a to_proto / from_proto of the mapping (Message's, lazy and generated ones): a
    subclass gets its own generated code in place of these, never in place of one written by hand."""
    fn.__vgr_mapped__ = True
    return fn


def install(cls: type) -> None:
    """Give *cls* lazy to_proto / from_proto unless it writes (or inherits) its own by hand."""
    for name in ("to_proto", "from_proto"):
        if _is_mapped(getattr(cls, name, None)):
            setattr(cls, name, _lazy(cls, name))


def _is_mapped(attr: Any) -> bool:
    return bool(getattr(getattr(attr, "__func__", attr), "__vgr_mapped__", False))


def _lazy(cls: type, name: str) -> Any:
    if name == "to_proto":
        return mapped(lambda self: codec_of(cls).to_proto(self))
    return classmethod(mapped(lambda k, pb, bulk: codec_of(cls).from_proto(k, pb, bulk)))


class _Code:
    """The source being written for one class: encoding statements, decoding set-up and arguments."""

    def __init__(self, cls: type) -> None:
        self.cls = cls
        self.enc: list[str] = []  # statements filling `pb` from the message `self`
        self.dec: list[str] = []  # statements before the decoding arguments
        self.args: list[str] = []  # `field=expression` of `pb` (and `bulk`)
        self.ns: dict[str, Any] = dict(_GLOBALS)
        self.bulk = "None"  # expression of the bulk bytes to_proto returns

    def const(self, name: str, value: Any) -> str:
        """*name*, bound to *value* in the generated code."""
        self.ns[name] = value
        return name

    def default(self, f: Any) -> str:
        if f.default_factory is not MISSING:
            return f"{self.const(f'_{f.name}_factory', f.default_factory)}()"
        return self.const(f"_{f.name}_default", f.default)


def _generate(cls: type) -> Codec:
    schema = getattr(cls, "SCHEMA", "")
    if not schema:
        raise MappingError(f"{cls.__name__} names no SCHEMA")
    pb_cls = proto_class(schema)
    desc = pb_cls.DESCRIPTOR  # type: ignore[attr-defined]
    try:
        hints = get_type_hints(cls)
    except NameError as exc:
        raise MappingError(f"{cls.__name__}: cannot resolve its annotations ({exc})") from None
    wire: WireMap = {}
    for base in reversed(cls.__mro__):
        wire.update(base.__dict__.get("WIRE", {}))
    code = _Code(cls)
    for f in fields(cls):  # type: ignore[arg-type]
        spec = wire.get(f.name, Wire())
        if spec is None:
            continue
        spec = Wire(spec) if isinstance(spec, str) else spec
        name = spec.name or f.name
        if spec.position is None and name not in desc.fields_by_name:
            if f.name in _BASE_FIELDS:
                continue
            raise MappingError(f"{cls.__name__}.{f.name}: schema {schema} has no field {name!r}")
        try:
            expr = _field(code, f, hints[f.name], spec, desc.fields_by_name.get(name))
        except MappingError as exc:
            raise MappingError(f"{cls.__name__}.{f.name} -> {schema}.{name}: {exc}") from None
        code.args.append(f"{f.name}={expr}")
    if getattr(cls, "BULK", None) is not None and code.bulk == "None":
        raise MappingError(f"{cls.__name__}: no field maps to its BULK field {cls.BULK}")  # type: ignore[attr-defined]
    code.ns["_new"] = pb_cls
    body, setup = ("".join(f"    {line}\n" for line in lines) for lines in (code.enc, code.dec))
    src = (
        f"def to_proto(self):\n    pb = _new()\n{body}    return pb, {code.bulk}\n\n"
        f"def fill(self, pb):\n{body}    return {code.bulk}\n\n"
        f"def from_proto(cls, pb, bulk):\n{setup}    return cls({', '.join(code.args)})\n"
    )
    filename = f"<message mapping {cls.__module__}.{cls.__qualname__}>"
    linecache.cache[filename] = (len(src), None, src.splitlines(True), filename)  # readable tracebacks
    exec(compile(src, filename, "exec"), code.ns)
    return Codec(code.ns["to_proto"], code.ns["from_proto"], code.ns["fill"], src)


def _field(code: _Code, f: Any, hint: Any, spec: Wire, pf: Any) -> str:
    """Add the encoding of field *f* to *code*; return the expression that decodes it."""
    a = f"self.{f.name}"
    members = get_args(hint) if get_origin(hint) in (Union, types.UnionType) else ()
    optional = type(None) in members
    t = next(x for x in members if x is not type(None)) if optional and len(members) == 2 else hint
    origin, targs = get_origin(t), get_args(t)
    if spec.position or spec.orientation:
        if not (spec.position and spec.orientation and t is np.ndarray):
            raise MappingError("a pose on two fields needs an array and both `position` and `orientation`")
        parts = f"pb.{spec.position}, pb.{spec.orientation}"
        code.enc.append(f"_set_pose_parts({parts}, {a})")
        return f"_pose_from_parts({parts})"
    p, sub, rep = f"pb.{pf.name}", pf.message_type and pf.message_type.full_name, _is_repeated(pf)
    if sub == _TIMESTAMP and not rep and t is int:
        ts = f"_ts_{f.name}"
        code.enc += [f"{ts} = {p}", f"{ts}.seconds, {ts}.nanos = divmod(int({a}), 1_000_000_000)"]
        code.dec.append(f"{ts} = {p}")
        return f"{ts}.seconds * 1_000_000_000 + {ts}.nanos"
    if sub == _POSE and not rep and t is np.ndarray:
        if spec.presence:
            code.enc.append(f"pb.{spec.presence} = {a} is not None")
        code.enc += [f"if {a} is not None:", f"    _set_pose({p}, {a})"] if optional else [f"_set_pose({p}, {a})"]
        if spec.presence:
            return f"(_get_pose({p}) if pb.{spec.presence} else None)"
        return f"(_get_pose({p}) if pb.HasField({pf.name!r}) else None)" if optional else f"_get_pose({p})"
    if sub == _POSE and origin is list and targs == (np.ndarray,):
        code.enc += [f"for _v in {a}:", f"    _set_pose({p}.add(), _v)"]
        return f"[_get_pose(_m) for _m in {p}]"
    if sub and rep and origin is dict and "name" in pf.message_type.fields_by_name:
        entry = [x for x in pf.message_type.fields if x.name != "name"]
        v = entry[0] if len(entry) == 1 else None
        if v is not None and v.message_type and v.message_type.full_name == _POSE:
            code.enc += [f"for _k, _v in {a}.items():", f"    _set_pose({p}.add(name=_k).{v.name}, _v)"]
            return f"{{_m.name: _get_pose(_m.{v.name}) for _m in {p}}}"
        if v is not None and v.message_type is None:
            code.enc += [f"for _k, _v in {a}.items():", f"    {p}.add(name=_k, {v.name}=float(_v))"]
            return f"{{_m.name: _m.{v.name} for _m in {p}}}"
    if sub and rep and origin is list and targs and getattr(targs[0], "SCHEMA", None) == sub:
        item = targs[0]
        fill = code.const(f"_fill_{f.name}", codec_of(item).fill)
        code.enc += [f"for _v in {a}:", f"    {fill}(_v, {p}.add())"]
        return f"[{code.const(f'_{f.name}_type', item)}.from_proto(_m, None) for _m in {p}]"
    if rep and not sub and t is np.ndarray and pf.cpp_type in _FLOATS:
        put = f"{p}.extend(_np.asarray({a}, dtype=float){'.ravel()' if spec.shape else ''}.tolist())"
        if optional:
            code.enc += [f"if {a} is not None:", f"    {put}"]
            return f"(_np.array({p}) if len({p}) else None)"
        code.enc.append(put)
        shape = f".reshape({spec.shape!r})" if spec.shape and len(spec.shape) > 1 else ""
        return f"_np.array({p}, dtype=float){shape}"
    if rep and not sub and origin is list and targs and targs[0] in _ELEMENTS:
        code.enc.append(f"{p}.extend({a})" if targs[0] is str else f"{p}.extend({targs[0].__name__}(_v) for _v in {a})")
        return f"list({p})"
    if not rep and not sub and pf.type == _BYTES and pf.number == getattr(code.cls, "BULK", None):
        if t is np.ndarray:
            if spec.dtype is None:
                raise MappingError("an array in the bulk field needs its dtype in WIRE")
            dt = code.const(f"_{f.name}_dtype", np.dtype(spec.dtype))
            code.enc.append(f"_bulk = _bytes_of(_np.asarray({a}, dtype={dt}))")
            code.bulk = "_bulk"
            return f"_np.frombuffer(bulk if bulk is not None else {p}, dtype={dt}).reshape({spec.shape or (-1,)!r})"
        code.enc.append(f"_bulk = {a}")
        code.bulk = '_bulk if type(_bulk) is bytes else memoryview(_bulk).cast("B")'
        return f"(bulk if bulk is not None else {p})"
    if not rep and not sub and pf.type == _STRING and t is not str:
        code.enc.append(f"{p} = _json.dumps({a}, sort_keys=True, default=_json_default)")
        return f"(_json.loads({p}) if {p} else {code.default(f)})"
    if not rep and not sub and t in (*_ELEMENTS, bytes):
        code.enc.append(f"{p} = {a}")
        return f"({p} or {code.default(f)})" if spec.unset_is_default else p
    raise MappingError(f"no encoding of {hint} in a {'repeated ' if rep else ''}{sub or pf.type} field")
