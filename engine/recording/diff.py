"""Comparing a replay's outputs with the recorded ones: identical, within tolerance, or different.

Streams are first compared byte for byte (payload and sequence number). Where bytes differ, both
messages are decoded and compared field by field: arrays and floats within ``rtol``/``atol`` are
"within tolerance" (the largest absolute difference is reported); anything else is "different",
with the first difference located as ``topic[seq].field[index]: recorded ... replayed ...``.
Event tracebacks are not compared (file paths differ between machines).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from engine.messages import codec

IDENTICAL, WITHIN, DIFFERENT = "identical", "within tolerance", "different"
IGNORED_FIELDS = frozenset({"traceback"})


@dataclass
class StreamVerdict:
    topic: str
    recorded: int
    replayed: int
    verdict: str
    first_difference: str = ""
    max_abs_diff: float = 0.0


def _short(v: Any) -> str:
    text = np.array2string(v, threshold=6, precision=9) if isinstance(v, np.ndarray) else repr(v)
    return text if len(text) <= 80 else text[:77] + "..."


def compare_values(a: Any, b: Any, path: str, rtol: float, atol: float) -> tuple[str, str, float]:
    """(verdict, first difference, max abs diff) of two decoded field values."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        if a.shape != b.shape:
            return DIFFERENT, f"{path}: shape {a.shape} recorded vs {b.shape} replayed", 0.0
        if a.dtype.kind in "fc" or b.dtype.kind in "fc":
            if np.array_equal(a, b, equal_nan=True):
                return IDENTICAL, "", 0.0
            close = np.isclose(a, b, rtol=rtol, atol=atol, equal_nan=True)
            finite = np.isfinite(a) & np.isfinite(b)
            diff = float(np.max(np.abs(a[finite] - b[finite]))) if finite.any() else float("inf")
            if close.all():
                return WITHIN, "", diff
            idx = tuple(int(i) for i in np.argwhere(~close)[0])
            return DIFFERENT, f"{path}{list(idx)}: recorded {a[idx].item()!r} vs replayed {b[idx].item()!r}", diff
        if np.array_equal(a, b):
            return IDENTICAL, "", 0.0
        idx = tuple(int(i) for i in np.argwhere(a != b)[0]) if a.ndim else ()
        return DIFFERENT, f"{path}{list(idx)}: recorded {_short(a[idx])} vs replayed {_short(b[idx])}", 0.0
    if isinstance(a, float) and isinstance(b, float):
        if a == b or (np.isnan(a) and np.isnan(b)):
            return IDENTICAL, "", 0.0
        if np.isclose(a, b, rtol=rtol, atol=atol):
            return WITHIN, "", abs(a - b)
        return DIFFERENT, f"{path}: recorded {a!r} vs replayed {b!r}", abs(a - b)
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return DIFFERENT, f"{path}: keys {sorted(a)} recorded vs {sorted(b)} replayed", 0.0
        return _combine(compare_values(a[k], b[k], f"{path}.{k}", rtol, atol) for k in sorted(a))
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        if len(a) != len(b):
            return DIFFERENT, f"{path}: {len(a)} items recorded vs {len(b)} replayed", 0.0
        return _combine(
            compare_values(x, y, f"{path}[{i}]", rtol, atol) for i, (x, y) in enumerate(zip(a, b, strict=False))
        )
    if hasattr(a, "__dict__") and type(a) is type(b):
        return compare_messages(a, b, path, rtol, atol)
    if isinstance(a, memoryview | bytes) and isinstance(b, memoryview | bytes):
        a, b = bytes(a), bytes(b)
    if a == b:
        return IDENTICAL, "", 0.0
    return DIFFERENT, f"{path}: recorded {_short(a)} vs replayed {_short(b)}", 0.0


def _combine(results: Any) -> tuple[str, str, float]:
    verdict, first, worst = IDENTICAL, "", 0.0
    for v, d, m in results:
        worst = max(worst, m)
        if v == DIFFERENT:
            return DIFFERENT, d, worst
        if v == WITHIN:
            verdict = WITHIN
    return verdict, first, worst


def compare_messages(a: Any, b: Any, path: str, rtol: float, atol: float) -> tuple[str, str, float]:
    fields = [k for k in vars(a) if k not in IGNORED_FIELDS and k != "seq"]
    return _combine(compare_values(getattr(a, k), getattr(b, k), f"{path}.{k}", rtol, atol) for k in fields)


def compare_stream(
    topic: str,
    type_name: str,
    recorded: list[tuple[int, bytes]],
    replayed: list[tuple[int, bytes]],
    rtol: float = 1e-9,
    atol: float = 1e-12,
) -> StreamVerdict:
    """Compare the (seq, payload) lists of one topic."""
    verdict, first, worst = IDENTICAL, "", 0.0

    def stream(outcome: str, detail: str, max_abs_diff: float = 0.0) -> StreamVerdict:
        return StreamVerdict(topic, len(recorded), len(replayed), outcome, detail, max_abs_diff)

    for i, ((sa, pa), (sb, pb)) in enumerate(zip(recorded, replayed, strict=False)):
        where = f"{topic}[seq {sa}]"
        if sa != sb:
            return stream(DIFFERENT, f"{topic}[message {i}]: seq {sa} recorded vs {sb} replayed")
        if bytes(pa) == bytes(pb):
            continue
        cls = codec.registry.get(type_name)
        try:
            ma, mb = codec.decode_payload(cls, pa), codec.decode_payload(cls, pb)
        except codec.CodecError as exc:
            return stream(DIFFERENT, f"{where}: undecodable: {exc}")
        v, d, m = compare_messages(ma, mb, where, rtol, atol)
        worst = max(worst, m)
        if v == DIFFERENT:
            return stream(DIFFERENT, d, worst)
        if v == WITHIN:
            verdict = WITHIN
        elif v == IDENTICAL and verdict == IDENTICAL:
            verdict = WITHIN  # bytes differ only in ignored fields
            first = first or f"{where}: differs only in ignored fields ({', '.join(sorted(IGNORED_FIELDS))})"
    if len(recorded) != len(replayed):
        return stream(DIFFERENT, f"{topic}: {len(recorded)} messages recorded, {len(replayed)} replayed", worst)
    return stream(verdict, first, worst)
