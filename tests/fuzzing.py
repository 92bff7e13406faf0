"""Shared pieces of the fuzz tests: hypothesis settings, byte/text mutation strategies and the outcome oracle.

Every fuzz test feeds a reader a file derived from a valid one (byte mutations, text-token mutations, structural
variants) and accepts exactly two outcomes (:func:`outcome`): a result that passes the test's own checks, or a
:class:`~cosemdepth.errors.CosemdepthError` whose message names the file. Anything else (another exception type,
a message without the path) fails the test.

The runs are deterministic by default (``derandomize=True``, no example database), so the suite is reproducible;
set ``COSEMDEPTH_FUZZ_RANDOM=1`` to explore new random examples and ``COSEMDEPTH_FUZZ_EXAMPLES=N`` to run ``N``
examples per test instead of each test's bound.
"""

from __future__ import annotations

import os
import struct
import zlib
from datetime import timedelta
from pathlib import Path
from typing import Callable, Iterable

from hypothesis import currently_in_test_context, event, settings
from hypothesis import strategies as st

from cosemdepth.errors import CosemdepthError

_RANDOM = bool(os.environ.get("COSEMDEPTH_FUZZ_RANDOM"))
_EXAMPLES = int(os.environ.get("COSEMDEPTH_FUZZ_EXAMPLES", "0"))


def fuzz_settings(max_examples: int, deadline_s: float = 5.0) -> settings:
    """Bounded settings for a fuzz test: ``max_examples`` examples, each under ``deadline_s`` seconds.

    The deadline is generous (the machine the suite runs on is shared): it is there to catch a reader that hangs
    or decodes a huge declared size, not to measure speed.
    """
    return settings(
        max_examples=_EXAMPLES or max_examples,
        deadline=timedelta(seconds=deadline_s),
        derandomize=not _RANDOM,
        database=None,
    )


# --------------------------------------------------------------------------------------------------------------
# Byte mutations

#: Values written over a header field by the "huge" mutation: sizes and lengths that would ask for gigabytes.
HUGE_WORDS = (b"\xff\xff\xff\xff", b"\x7f\xff\xff\xff", b"\x80\x00\x00\x00", b"\x00\x01\x00\x00", b"\xff\xff")


@st.composite
def _position(draw, n: int, head: int = 64) -> int:
    """A position in ``0..n`` (inclusive), half of the time in the first ``head`` bytes (where headers are)."""
    if n <= 0:
        return 0
    if draw(st.booleans()):
        return draw(st.integers(0, min(n, head)))
    return draw(st.integers(0, n))


@st.composite
def mutate_bytes(draw, data: bytes, max_ops: int = 3) -> bytes:
    """``data`` after 1..``max_ops`` random mutations: truncation, byte flips, inserted/deleted/overwritten bytes,
    a huge 4-byte word written over a header field, or emptied."""
    out = bytearray(data)
    for _ in range(draw(st.integers(1, max_ops))):
        op = draw(st.sampled_from(("truncate", "flip", "insert", "delete", "overwrite", "huge", "empty")))
        n = len(out)
        if op == "truncate":
            del out[draw(st.integers(0, n)) :]
        elif op == "empty":
            out = bytearray()
        elif op == "flip" and n:
            i = min(draw(_position(n)), n - 1)
            out[i] ^= 1 << draw(st.integers(0, 7))
        elif op == "insert":
            i = draw(_position(n))
            out[i:i] = draw(st.binary(min_size=1, max_size=16))
        elif op == "delete" and n:
            i = min(draw(_position(n)), n - 1)
            del out[i : i + draw(st.integers(1, 16))]
        elif op == "overwrite" and n:
            i = min(draw(_position(n)), n - 1)
            chunk = draw(st.binary(min_size=1, max_size=8))
            out[i : i + len(chunk)] = chunk
        elif op == "huge" and n:
            i = min(draw(_position(n)), n - 1)
            word = draw(st.sampled_from(HUGE_WORDS))
            out[i : i + len(word)] = word
    return bytes(out)


# --------------------------------------------------------------------------------------------------------------
# Text mutations (numeric text files: pose files, split CSVs, split lists)

#: Tokens that replace a field of a text file: non-numbers, NaN/inf, overflowing numbers, odd separators,
#: control characters, quotes, huge integers.
BAD_TOKENS = (
    "",
    "nan",
    "NaN",
    "-inf",
    "inf",
    "1e999",
    "-1e400",
    "1e38",
    "1e300",
    "-1e300",
    "abc",
    "0x10",
    "1_0",
    "1,5",
    "--1",
    "\x00",
    "\t",
    " ",
    '"',
    '"unterminated',
    "é",
    "\u2028",
    "#",
    "9" * 30,
    "-" + "9" * 30,
    "1e-320",
    "4.9e-324",
    "True",
    "None",
    "[1]",
    "x" * 5000,  # longer than a file name may be (ENAMETOOLONG)
)


@st.composite
def mutate_text(draw, text: str, separators: str = " \t,\n", max_ops: int = 3) -> str:
    """``text`` after 1..``max_ops`` token-level mutations: a field replaced by a :data:`BAD_TOKENS` entry, by
    random text or by a very long token, a field or line duplicated/deleted, a separator inserted, the text
    truncated."""
    import re

    for _ in range(draw(st.integers(1, max_ops))):
        tokens = re.split(f"([{re.escape(separators)}]+)", text)
        fields = [i for i in range(0, len(tokens), 2)]
        op = draw(
            st.sampled_from(
                ("bad", "bad", "random", "long", "dup_field", "del_field", "sep", "truncate", "dup_line", "del_line")
            )
        )
        if op in ("bad", "random", "long", "dup_field", "del_field", "sep") and fields:
            i = draw(st.sampled_from(fields))
            if op == "bad":
                tokens[i] = draw(st.sampled_from(BAD_TOKENS))
            elif op == "long":  # longer than the csv module's field limit (131,072 characters)
                tokens[i] = draw(st.sampled_from("1a ")) * 200_000
            elif op == "random":
                tokens[i] = draw(st.text(max_size=8))
            elif op == "dup_field":
                tokens[i] = tokens[i] + draw(st.sampled_from(separators)) + tokens[i]
            elif op == "del_field":
                tokens[i] = ""
            else:
                tokens[i] = tokens[i] + draw(st.sampled_from(separators))
            text = "".join(tokens)
        elif op == "truncate":
            text = text[: draw(st.integers(0, len(text)))]
        else:
            lines = text.splitlines(keepends=True)
            if lines:
                k = draw(st.integers(0, len(lines) - 1))
                lines[k : k + 1] = [lines[k]] * 2 if op == "dup_line" else []
            text = "".join(lines)
    return text


@st.composite
def text_file_bytes(draw, text: str, separators: str = " \t,\n") -> bytes:
    """File contents derived from ``text``: text mutations (UTF-8 encoded), byte mutations (which may make it
    non-UTF-8), a non-UTF-8 (Latin-1) encoding, or the text unchanged."""
    kind = draw(st.sampled_from(("text", "text", "bytes", "latin1", "same")))
    if kind == "text":
        return draw(mutate_text(text, separators)).encode("utf-8", errors="surrogatepass")
    if kind == "bytes":
        return draw(mutate_bytes(text.encode()))
    if kind == "latin1":
        return (text + "\u00e9\u00ff").encode("latin-1")
    return text.encode()


# --------------------------------------------------------------------------------------------------------------
# Image headers


def png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def png_with_size(data: bytes, width: int, height: int) -> bytes:
    """A PNG whose IHDR declares ``width`` x ``height`` (with a valid CRC), the rest of ``data`` unchanged."""
    ihdr = bytearray(data[16:29])
    ihdr[0:8] = struct.pack(">II", width, height)
    return data[:8] + png_chunk(b"IHDR", bytes(ihdr)) + data[33:]


def jpeg_with_size(data: bytes, width: int, height: int) -> bytes:
    """A JPEG whose (first) SOF segment declares ``width`` x ``height``, the rest of ``data`` unchanged."""
    i = 2
    while i + 4 <= len(data):
        marker, length = data[i + 1], struct.unpack(">H", data[i + 2 : i + 4])[0]
        if marker in (0xC0, 0xC1, 0xC2):
            return data[: i + 5] + struct.pack(">HH", height, width) + data[i + 9 :]
        i += 2 + length
    raise ValueError("no SOF segment")


# --------------------------------------------------------------------------------------------------------------
# The oracle


def outcome(call: Callable[[], object], paths: Iterable[str | os.PathLike], check: Callable[[object], None]):
    """Run ``call``; a :class:`CosemdepthError` must name one of ``paths`` (returns None); a result must pass
    ``check`` (returns the result). Any other exception propagates and fails the test."""
    names = [os.fspath(p) for p in paths]
    try:
        result = call()
    except CosemdepthError as e:
        _event(f"error: {type(e).__name__}")
        msg = str(e)
        assert any(n in msg for n in names), f"error message does not name the file {names}: {msg!r}"
        assert "\n" not in msg, f"error message is not one line: {msg!r}"
        return None
    _event("result")
    check(result)
    return result


def _event(what: str) -> None:
    """Count an outcome in hypothesis' statistics (``--hypothesis-show-statistics``); a no-op in plain tests."""
    if currently_in_test_context():
        event(what)


def write(path: Path, data: bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


def png_bytes(arr, bit_depth: int, colour_type: int, palette: bytes | None = None) -> bytes:
    """A PNG of any bit depth / colour type, written from its definition (no Pillow): ``arr`` is ``[H, W]`` or
    ``[H, W, C]`` of sample values (packed for bit depths < 8, big-endian for 16), one zlib stream, filter 0."""
    import numpy as np

    a = np.asarray(arr)
    if a.ndim == 2:
        a = a[..., None]
    h, w, c = a.shape
    if bit_depth == 16:
        rows = a.astype(">u2").reshape(h, w * c).view(np.uint8).reshape(h, -1)
    elif bit_depth == 8:
        rows = a.astype(np.uint8).reshape(h, w * c)
    else:
        rows = np.packbits(
            np.unpackbits(a.astype(np.uint8).reshape(h, w * c, 1), axis=2)[:, :, 8 - bit_depth :].reshape(h, -1),
            axis=1,
        )
    raw = b"".join(b"\x00" + r.tobytes() for r in rows)
    out = b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, bit_depth, colour_type, 0, 0, 0))
    if palette is not None:
        out += png_chunk(b"PLTE", palette)
    return out + png_chunk(b"IDAT", zlib.compress(raw)) + png_chunk(b"IEND", b"")
