"""A generated CDR codec per ROS 2 type: TypeSupport bodies straight to rmw_zenoh's bytes and back.

rosbags' serializer is the reference (``types.Ros2Codec`` falls back to it), but its path is body ->
rosbags dataclass (numpy arrays for numeric arrays) -> bytes and back, which costs 15-40 us a
message: the ROS 2 wire's p50 was 1.76x raw with it (docs/benchmarks.md). This module writes, once
per type, Python source that packs a body (field values in declaration order, nested messages as
lists) into XCDR1 little-endian with one ``struct.Struct`` per run of fixed-size fields (nested
types inlined, alignment padding resolved at generation time wherever the offset is known, at run
time after strings and sequences), and unpacks it back into the lists ``TypeSupport.decode``
validates. The bytes are rosbags' bytes (tests/library/test_fastcdr.py checks them with hypothesis):

- every primitive is aligned to its size relative to the byte after the 4-byte encapsulation
  header; a sequence's elements only when it has some (as rosbags does); no padding at the end;
- ``byte`` scalars pack as int8 and ``char`` as uint8, as rosbags' primitives do; ``uint8``,
  ``byte`` and ``char`` arrays decode to ``bytes``, other arrays to lists.

What it does not cover it leaves to rosbags: a type with a ``wstring`` or a nested array gets no
fast codec (:func:`build` returns None), and any exception while packing or unpacking makes the
caller redo the sample through rosbags, so a body or payload rosbags rejects fails with rosbags'
error and one it accepts in a way this code did not foresee still gets rosbags' bytes.

Threading: the generated functions are pure; generation is the caller's business (types.py holds
its lock while it makes a type).
"""
from __future__ import annotations

import array
import struct
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

HEADER = b"\x00\x01\x00\x00"      # CDR little endian, no options (all rmw_zenoh sends)
MAX_TRAILING = 3                   # bytes after the body rosbags accepts (alignment padding)

_CODES = {"bool": "?", "byte": "b", "char": "B", "int8": "b", "uint8": "B", "int16": "h", "uint16": "H",
          "int32": "i", "uint32": "I", "int64": "q", "uint64": "Q", "float32": "f", "float64": "d"}
_SIZES = {"bool": 1, "byte": 1, "char": 1, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2, "int32": 4,
          "uint32": 4, "int64": 8, "uint64": 8, "float32": 4, "float64": 8}
# array module type codes of sequence elements (bool and the byte types are handled apart).
_ARRAY = {"int8": "b", "int16": "h", "uint16": "H", "int32": "i", "uint32": "I", "int64": "q", "uint64": "Q",
          "float32": "f", "float64": "d"}
_BYTES = ("uint8", "byte", "char")


class Unsupported(Exception):
    """A type the generator leaves to rosbags."""


Encode = Callable[[Any], bytes]
Decode = Callable[[bytes | memoryview, bool], list[Any]]


@dataclass(frozen=True)
class FastCodec:
    """One type's generated codec. ``encode(body) -> payload`` (header included);
    ``decode(payload, cut_trailing) -> body``: raises on bytes that are not the type's CDR (the
    caller then asks rosbags, for its error); ``cut_trailing`` ignores any bytes after the body
    instead of more than 3. ``source`` is the generated code (for debugging and tests)."""
    encode: Encode
    decode: Decode
    source: str = field(repr=False)


@dataclass
class _Field:
    kind: str            # prim, string, seq, strseq, nested, narray, nseq, farray, fstrarray
    base: str            # primitive name or nested type name
    count: int = 0       # fixed arrays


def _fields(store: Any, name: str) -> list[_Field]:
    out = []
    for fname, (node, arg) in store.fielddefs[name][1]:
        kind = node.name
        if kind == "BASE":
            base = arg[0]
            if base == "wstring":
                raise Unsupported(f"{name}.{fname}: wstring")
            out.append(_Field("string", base) if base == "string" else _Field("prim", base))
        elif kind == "NAME":
            out.append(_Field("nested", arg))
        else:
            (sub_node, sub_arg), size = arg
            fixed = kind == "ARRAY"
            if sub_node.name == "NAME":
                out.append(_Field("narray", sub_arg, size) if fixed else _Field("nseq", sub_arg))
            elif sub_node.name == "BASE":
                base = sub_arg[0]
                if base == "wstring":
                    raise Unsupported(f"{name}.{fname}: wstring[]")
                if base == "string":
                    out.append(_Field("fstrarray", base, size) if fixed else _Field("strseq", base))
                else:
                    out.append(_Field("farray", base, size) if fixed else _Field("seq", base))
            else:
                raise Unsupported(f"{name}.{fname}: nested arrays")
    if not out:
        raise Unsupported(f"{name}: no fields")
    return out


class _Source:
    def __init__(self) -> None:
        self.lines: list[str] = []
        self.consts: dict[str, Any] = {}
        self._n = 0

    def name(self, prefix: str) -> str:
        self._n += 1
        return f"{prefix}{self._n}"

    def struct(self, fmt: str) -> str:
        key = "S_" + fmt.replace("?", "o")
        self.consts.setdefault(key, struct.Struct("<" + fmt))
        return key


class _Gen:
    """Writes one type's encoder and decoder, and a helper pair per type nested in an array or sequence."""

    def __init__(self, store: Any) -> None:
        self.store = store
        self.src = _Source()
        self.helpers: dict[str, tuple[str, str]] = {}

    def first_align(self, name: str) -> int:
        f = _fields(self.store, name)[0]
        if f.kind in ("prim", "farray"):
            return _SIZES[f.base]
        if f.kind in ("nested", "narray"):
            return self.first_align(f.base)
        return 4

    def helper(self, name: str) -> tuple[str, str]:
        """(encoder, decoder) function names of a nested type, generated once."""
        got = self.helpers.get(name)
        if got is None:
            got = self.helpers[name] = (self.src.name("enc_"), self.src.name("dec_"))
            align = self.first_align(name)    # the caller aligns to it before each element
            _Encoder(self, name, got[0], align).write()
            _Decoder(self, name, got[1], align).write()
        return got


class _Writer:
    """The state both directions share: lines, the pending fixed-size run, what is known of the offset
    (``pos`` is congruent to ``rem`` modulo ``mod``)."""

    def __init__(self, gen: _Gen, mod: int) -> None:
        self.gen = gen
        self.src = gen.src
        self.body: list[str] = []
        self.mod, self.rem = mod, 0
        self.fmt = ""
        self.size = 0

    def emit(self, line: str, indent: int = 1) -> None:
        self.body.append("    " * indent + line)

    def place(self, size: int, count: int = 1) -> bool:
        """Pad the run for a ``size``-aligned item of ``count`` x ``size`` bytes; False when the offset
        is not known well enough (flush, then :meth:`align` at run time, then place again)."""
        if size > self.mod:
            return False
        pad = (-self.rem) % size
        self.fmt += "x" * pad
        self.size += pad + size * count
        self.rem = (self.rem + pad + size * count) % self.mod
        return True

    def runtime_align(self, size: int) -> None:
        """Align ``pos`` at run time (the run is flushed): known from here on modulo ``size``."""
        if size > 1:
            self.align_line(size)
        self.mod, self.rem = max(size, 1), 0

    def align_line(self, size: int) -> None:
        raise NotImplementedError

    def unknown(self, mod: int) -> None:
        self.mod, self.rem = mod, 0


class _Encoder(_Writer):
    """``def f(v[, out, pos]) -> pos``: appends the bytes of body ``v`` to ``out`` (pos: bytes after
    the header so far)."""

    def __init__(self, gen: _Gen, name: str, fname: str, mod: int) -> None:
        super().__init__(gen, mod)
        self.name, self.fname = name, fname
        self.args: list[str] = []

    def align_line(self, size: int) -> None:
        self.emit(f"pad = -pos & {size - 1}")
        self.emit("if pad:")
        self.emit("out.append(ZEROS[pad]); pos += pad", 2)

    def flush(self) -> None:
        if self.fmt:
            s = self.src.struct(self.fmt)
            self.emit(f"out.append({s}.pack({', '.join(self.args)})); pos += {self.size}")
        self.fmt, self.size, self.args = "", 0, []

    def prim(self, expr: str, base: str, count: int = 1) -> None:
        size = _SIZES[base]
        if not self.place(size, count):
            self.flush()
            self.runtime_align(size)
            self.place(size, count)
        # uint8/byte/char arrays are bytes in a body: packed unsigned whatever the scalar's sign
        code = "B" if count != 1 and base in _BYTES else _CODES[base]
        self.fmt += f"{count if count != 1 else ''}{code}"
        self.args.append(expr if count == 1 else f"*{expr}")

    def string(self, expr: str) -> None:
        var = self.src.name("s")
        self.emit(f"{var} = {expr}.encode()")
        self.prim(f"len({var}) + 1", "uint32")
        self.flush()
        self.emit(f"out.append({var}); out.append(NUL); pos += len({var}) + 1")
        self.unknown(1)

    def field(self, f: _Field, expr: str) -> None:
        if f.kind == "prim":
            self.prim(expr, f.base)
        elif f.kind == "farray":
            self.emit(f"if len({expr}) != {f.count}: raise ValueError('array length')")
            self.prim(expr, f.base, f.count)
        elif f.kind == "string":
            self.string(expr)
        elif f.kind == "fstrarray":
            self.emit(f"if len({expr}) != {f.count}: raise ValueError('array length')")
            for i in range(f.count):
                self.string(f"{expr}[{i}]")
        elif f.kind == "nested":
            var = self.src.name("n")
            self.emit(f"{var} = {expr}")
            for i, sub in enumerate(_fields(self.gen.store, f.base)):
                self.field(sub, f"{var}[{i}]")
        elif f.kind == "narray":
            self.emit(f"if len({expr}) != {f.count}: raise ValueError('array length')")
            self.elements(f, expr)
        else:   # the sequences: count, then the elements
            var = self.src.name("q")
            self.emit(f"{var} = {expr}")
            self.prim(f"len({var})", "uint32")
            self.flush()
            self.unknown(4)
            self.sequence(f, var)

    def sequence(self, f: _Field, var: str) -> None:
        if f.kind == "strseq":
            self.emit(f"for x in {var}:")
            self.emit("x = x.encode(); pad = -pos & 3", 2)
            self.emit("out.append(ZEROS[pad]); out.append(U32.pack(len(x) + 1)); out.append(x); out.append(NUL)", 2)
            self.emit("pos += pad + 5 + len(x)", 2)
            self.unknown(1)
        elif f.kind == "nseq":
            self.elements(f, var)
        elif f.base in _BYTES:
            self.emit(f"b = bytes({var}); out.append(b); pos += len(b)")
            self.unknown(1)
        else:
            size = _SIZES[f.base]
            self.emit(f"if {var}:")
            if size > 4:
                self.emit(f"pad = -pos & {size - 1}", 2)
                self.emit("out.append(ZEROS[pad]); pos += pad", 2)
            if f.base == "bool":
                self.emit(f"b = struct.pack('<%d?' % len({var}), *{var})", 2)
            else:
                self.emit(f"b = array('{_ARRAY[f.base]}', {var}).tobytes()", 2)
            self.emit("out.append(b); pos += len(b)", 2)
            self.unknown(min(4, size))

    def elements(self, f: _Field, var: str) -> None:
        self.flush()
        enc, _ = self.gen.helper(f.base)
        align = self.gen.first_align(f.base)
        self.emit(f"for x in {var}:")
        if align > 1:
            self.emit(f"pad = -pos & {align - 1}", 2)
            self.emit("if pad:", 2)
            self.emit("out.append(ZEROS[pad]); pos += pad", 3)
        self.emit(f"pos = {enc}(x, out, pos)", 2)
        self.unknown(1)

    def write(self) -> None:
        for i, f in enumerate(_fields(self.gen.store, self.name)):
            self.field(f, f"v[{i}]")
        self.flush()
        self.src.lines += [f"def {self.fname}(v, out, pos):", *self.body, "    return pos", ""]


class _Decoder(_Writer):
    """``def f(buf, p, end) -> (body, p)``; ``p`` is an index into the payload (header included), so
    run-time alignment is of ``p - 4``."""

    def __init__(self, gen: _Gen, name: str, fname: str, mod: int) -> None:
        super().__init__(gen, mod)
        self.name, self.fname = name, fname
        self.run_var = ""
        self.index = 0

    def align_line(self, size: int) -> None:
        self.emit(f"p += (4 - p) & {size - 1}")

    def flush(self) -> None:
        if self.fmt:
            s = self.src.struct(self.fmt)
            self.emit(f"{self.run_var} = {s}.unpack_from(buf, p); p += {self.size}")
        self.fmt, self.size, self.run_var, self.index = "", 0, "", 0

    def prim(self, base: str, count: int = 1) -> str:
        """Add to the run; the expression of the value(s) once the run is unpacked."""
        size = _SIZES[base]
        if not self.place(size, count):
            self.flush()
            self.runtime_align(size)
            self.place(size, count)
        if not self.run_var:
            self.run_var = self.src.name("r")
        i = self.index
        if count != 1 and base in _BYTES:
            self.fmt += f"{count}s"
            self.index += 1
            return f"{self.run_var}[{i}]"
        self.fmt += f"{count if count != 1 else ''}{_CODES[base]}"
        self.index += count
        return f"{self.run_var}[{i}]" if count == 1 else f"list({self.run_var}[{i}:{i + count}])"

    def string(self) -> str:
        n = self.prim("uint32")
        self.flush()
        var = self.src.name("s")
        self.emit(f"n = {n}; e = p + n")
        self.emit("if n < 1 or e > end or buf[e - 1]: raise ValueError('bad string')")
        self.emit(f"{var} = buf[p:e - 1].decode(); p = e")
        self.unknown(1)
        return var

    def field(self, f: _Field) -> str:
        if f.kind == "prim":
            return self.prim(f.base)
        if f.kind == "farray":
            return self.prim(f.base, f.count)
        if f.kind == "string":
            return self.string()
        if f.kind == "fstrarray":
            return "[" + ", ".join(self.string() for _ in range(f.count)) + "]"
        if f.kind == "nested":
            return "[" + ", ".join(self.field(sub) for sub in _fields(self.gen.store, f.base)) + "]"
        if f.kind == "narray":
            return self.elements(f, str(f.count))
        count = self.src.name("c")
        n = self.prim("uint32")
        self.flush()
        self.emit(f"{count} = {n}")
        self.unknown(4)
        return self.sequence(f, count)

    def sequence(self, f: _Field, count: str) -> str:
        var = self.src.name("q")
        if f.kind == "strseq":
            self.emit(f"if p + {count} * 5 > end: raise ValueError('bad sequence')")
            self.emit(f"{var} = []")
            self.emit(f"for _ in range({count}):")
            self.emit("p += (4 - p) & 3; n, = U32.unpack_from(buf, p); p += 4; e = p + n", 2)
            self.emit("if n < 1 or e > end or buf[e - 1]: raise ValueError('bad string')", 2)
            self.emit(f"{var}.append(buf[p:e - 1].decode()); p = e", 2)
            self.unknown(1)
            return var
        if f.kind == "nseq":
            self.emit(f"if p + {count} > end: raise ValueError('bad sequence')")
            return self.elements(f, count)
        size = _SIZES[f.base]
        self.emit(f"if {count} and p + {count} * {size} > end: raise ValueError('bad sequence')")
        if size > 4:
            self.emit(f"if {count}: p += (4 - p) & {size - 1}")
        self.emit(f"e = p + {count} * {size}")
        self.emit("if e > end: raise ValueError('bad sequence')")
        if f.base in _BYTES:
            self.emit(f"{var} = buf[p:e]; p = e")
        elif f.base == "bool":
            self.emit(f"{var} = [x != 0 for x in buf[p:e]]; p = e")
        else:
            self.emit(f"a = array('{_ARRAY[f.base]}'); a.frombytes(buf[p:e]); {var} = a.tolist(); p = e")
        self.unknown(min(4, size))
        return var

    def elements(self, f: _Field, count: str) -> str:
        self.flush()
        _, dec = self.gen.helper(f.base)
        align = self.gen.first_align(f.base)
        var = self.src.name("q")
        self.emit(f"{var} = []")
        self.emit(f"for _ in range({count}):")
        if align > 1:
            self.emit(f"p += (4 - p) & {align - 1}", 2)
        self.emit(f"x, p = {dec}(buf, p, end); {var}.append(x)", 2)
        self.unknown(1)
        return var

    def write(self) -> None:
        values = [self.field(f) for f in _fields(self.gen.store, self.name)]
        self.flush()
        self.src.lines += [f"def {self.fname}(buf, p, end):", *self.body,
                           f"    return [{', '.join(values)}], p", ""]


def build(store: Any, name: str) -> FastCodec | None:
    """The generated codec of the ROS 2 type ``name`` of a rosbags typestore, or None for a type it
    does not cover (rosbags then does the work)."""
    if sys.byteorder != "little":   # array.tobytes() is native order
        return None
    gen = _Gen(store)
    try:
        enc = _Encoder(gen, name, "enc_top", 8)
        enc.write()
        dec = _Decoder(gen, name, "dec_top", 8)
        dec.write()
    except Unsupported:
        return None
    src = gen.src
    src.lines += [
        "def encode(v):",
        "    out = [HEADER]",
        "    enc_top(v, out, 0)",
        "    return b''.join(out)",
        "",
        "def decode(buf, cut_trailing):",
        "    if type(buf) is not bytes: buf = bytes(buf)",
        "    end = len(buf)",
        "    if buf[:2] != HEADER[:2]: raise ValueError('not little-endian CDR')",
        "    body, p = dec_top(buf, 4, end)",
        "    if p > end: raise ValueError('truncated')",
        f"    if not cut_trailing and end - p > {MAX_TRAILING}: raise ValueError('trailing bytes')",
        "    return body",
    ]
    source = "\n".join(src.lines) + "\n"
    namespace: dict[str, Any] = {"array": array.array, "struct": struct, "HEADER": HEADER, "NUL": b"\x00",
                                 "ZEROS": [bytes(i) for i in range(8)], "U32": struct.Struct("<I"), **src.consts}
    exec(compile(source, f"<fastcdr {name}>", "exec"), namespace)   # noqa: S102 - our own generated source
    return FastCodec(namespace["encode"], namespace["decode"], source)
