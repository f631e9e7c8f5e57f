"""Golden samples: one message of every type, as a release's encoder writes it.

How this works: the generator walks the message schema of whatever
``ramps.core.messages`` is importable (``msgspec.inspect``) and builds, for
every message type, a *full* sample (every field set, to a value that is not
its default and fits its limits) and a *minimal* one (required fields only),
deterministically. Each is encoded with that release's own ``encode`` and
written as ``<type>-full.msgpack`` / ``<type>-minimal.msgpack`` beside
``manifest.json`` (the release, its protocol, and each sample's fields as
JSON, bytes in base64), so a later release's test can decode the bytes and
compare field by field (tests/test_wire_golden.py).

Run it against an old release from a checkout of its tag, with this
repository's virtual environment:

    git worktree add /tmp/ramps-0.1.0 v0.1.0
    PYTHONPATH=/tmp/ramps-0.1.0/src .venv/bin/python tests/golden/make_samples.py tests/golden/0.1.0
    git worktree remove /tmp/ramps-0.1.0

Rules: it uses nothing but msgspec and the struct constructors and
``encode`` every release has had, so it runs unchanged against 0.1.0; the
samples of a release are made once, when it is tagged, and never edited.
"""

from __future__ import annotations

import json
import re
import sys
import typing
from pathlib import Path
from typing import Any

import msgspec
import msgspec.inspect as mi

#: the name every sample is sent by
SENDER = "r1"


def _int(t: mi.IntType) -> int:
    lo = t.ge if t.ge is not None else (t.gt + 1 if t.gt is not None else None)
    hi = t.le if t.le is not None else (t.lt - 1 if t.lt is not None else None)
    v = 3
    if lo is not None:
        v = max(v, lo)
    if hi is not None:
        v = min(v, hi)
    return v


def _float(t: mi.FloatType) -> float:
    v = 0.5
    lo = t.ge if t.ge is not None else t.gt
    hi = t.le if t.le is not None else t.lt
    if lo is not None and v <= lo:
        v = lo * 2 if lo > 0 else lo + 1.0
    if hi is not None and v >= hi:
        v = hi / 2
    return v


def _str(t: mi.StrType) -> str:
    for cand in ("r1", "busy", "x"):
        if t.pattern is not None and not re.search(t.pattern, cand):
            continue
        if (t.min_length or 0) <= len(cand) <= (t.max_length if t.max_length is not None else 1 << 30):
            return cand
    raise ValueError(f"no sample string for {t}")


def value(t: mi.Type, full: bool) -> Any:
    """A valid value of type ``t`` (not the field's default where it can help it)."""
    if isinstance(t, mi.Metadata):
        return value(t.type, full)
    if isinstance(t, mi.BoolType):
        return True
    if isinstance(t, mi.IntType):
        return _int(t)
    if isinstance(t, mi.FloatType):
        return _float(t)
    if isinstance(t, mi.StrType):
        return _str(t)
    if isinstance(t, mi.BytesType):
        return b"\x93\x01\x02\x03"[: t.max_length if t.max_length is not None else 4]
    if isinstance(t, mi.ListType):
        return [value(t.item_type, full)]
    if isinstance(t, mi.UnionType):
        return value(next(x for x in t.types if not isinstance(x, mi.NoneType)), full)
    if isinstance(t, mi.StructType):
        return struct(t, full)
    raise TypeError(f"no sample value for {t!r}")


def struct(t: mi.StructType, full: bool) -> Any:
    kw = {f.name: value(f.type, full) for f in t.fields if full or f.required}
    return t.cls(**kw)


def samples(m: Any) -> dict[str, Any]:
    """``{name: message}``: a full and a minimal sample of every message type of module ``m``."""
    out: dict[str, Any] = {}
    for cls in typing.get_args(m.Message):
        info = mi.type_info(cls)
        tag = cls.__struct_config__.tag
        out[f"{tag}-full"] = struct(info, True)
        out[f"{tag}-minimal"] = struct(info, False)
    return out


def fields(msg: Any) -> dict:
    """A message's fields as JSON-able builtins (bytes in base64), its tag included."""
    return json.loads(msgspec.json.encode(msg))


def release_of(m: Any) -> tuple[str, str]:
    """(ramps version, protocol) of the imported code; 0.1.0 had only ``PROTOCOL_VERSION``."""
    import ramps

    protocol = getattr(m, "PROTOCOL", None) or f"{m.PROTOCOL_VERSION}.0"
    return ramps.__version__, protocol


def write(out_dir: Path) -> dict:
    from ramps.core import messages as m

    out_dir.mkdir(parents=True, exist_ok=True)
    release, protocol = release_of(m)
    manifest: dict = {"release": release, "protocol": protocol, "sender": SENDER, "samples": {}}
    for name, msg in samples(m).items():
        data = m.encode(SENDER, msg)
        assert m.decode(data).msg == msg, name  # the release itself reads it back
        (out_dir / f"{name}.msgpack").write_bytes(data)
        manifest["samples"][name] = {"type": type(msg).__name__, "fields": fields(msg)}
    (out_dir / "manifest.json").write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    return manifest


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    man = write(Path(sys.argv[1]))
    print(f"ramps {man['release']} (protocol {man['protocol']}): {len(man['samples'])} samples in {sys.argv[1]}")
