"""Text files read without holding them: a counting pass, then blocks of whole lines.

Shared by the text readers (``_table.parse_rows``): UTF-8 with an optional byte order mark;
binary data (a NUL byte) and invalid UTF-8 are errors naming file and line.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from ..errors import FormatError

__all__ = ["first_data_line", "plain_ascii", "read_lines", "scan_text", "text_blocks"]

#: ASCII whitespace of ``str.split()``/``str.strip()`` besides space, tab and newline.
_OTHER_SPACE = "\x0b\x0c\r\x1c\x1d\x1e\x1f"


def scan_text(path: Path, chunk_bytes: int = 1 << 20) -> tuple[int, bool, int, int]:
    """Lines of a text file, whether the last one is unterminated, that line's byte length,
    and the bytes of text (without a byte order mark), in one pass over the bytes; a NUL byte
    (binary or zero-filled data) raises ``ValueError`` naming file and line."""
    n_lines = 0
    last = 0  # bytes after the last newline
    size = 0
    with open(path, "rb") as f:
        first = True
        while chunk := f.read(chunk_bytes):
            if first and chunk.startswith(b"\xef\xbb\xbf"):  # UTF-8 byte order mark
                chunk = chunk[3:]
            first = False
            nul = chunk.find(b"\0")
            if nul >= 0:
                line = n_lines + chunk[:nul].count(b"\n") + 1
                raise FormatError(f"{path}:{line}: not a text recording (binary data: NUL byte)")
            n_lines += chunk.count(b"\n")
            nl = chunk.rfind(b"\n")
            last = len(chunk) - nl - 1 if nl >= 0 else last + len(chunk)
            size += len(chunk)
    unterminated = last > 0
    return n_lines + unterminated, unterminated, last, size


def text_blocks(path: Path, block_bytes: int) -> Iterator[tuple[int, list[str], bool]]:
    """``(index of the first line, lines, plain)`` of a text file, a block of about
    ``block_bytes`` of whole lines at a time (UTF-8, a leading byte order mark skipped); invalid
    UTF-8 raises ``ValueError`` naming file and line. A block ends at a newline, so no UTF-8
    sequence is ever split. ``plain``: the block is ASCII without comments (``#``) or
    whitespace other than spaces, tabs and newlines (:func:`plain_ascii`)."""
    line0 = 0
    carry = b""
    with open(path, "rb") as f:
        head = f.read(3)
        if head != b"\xef\xbb\xbf":
            carry = head
        while True:
            chunk = f.read(max(block_bytes, len(carry), 1))  # a long line: reads double
            raw = carry + chunk
            cut = raw.rfind(b"\n") + 1 if chunk else len(raw)
            if cut == 0:  # no complete line yet (or nothing left): read on
                if not chunk:
                    return
                carry = raw
                continue
            block, carry = raw[:cut], raw[cut:]
            try:
                text = block.decode("utf-8")
            except UnicodeDecodeError as exc:
                line = line0 + block[: exc.start].count(b"\n") + 1
                raise FormatError(f"{path}:{line}: not UTF-8 text ({exc.reason})") from exc
            del block, raw
            plain = plain_ascii(text) and "#" not in text
            lines = text.split("\n")
            del text
            if lines and lines[-1] == "":
                lines.pop()  # a block ends in a newline (or is the unterminated tail)
            if lines:
                yield line0, lines, plain
            line0 += len(lines)
            if not chunk:
                return


def plain_ascii(text: str) -> bool:
    """ASCII without the whitespace ``str.split()`` and ``str.strip()`` see besides space,
    tab and newline (vertical tab, form feed, carriage return, separators 0x1c-0x1f)."""
    return text.isascii() and not any(c in text for c in _OTHER_SPACE)


def first_data_line(path: Path) -> str | None:
    """The first line that is neither blank nor a ``#`` comment (stripped), or ``None``.

    Reads only as far as that line; binary data (a NUL byte anywhere) raises ``ValueError``
    as the readers do.
    """
    scan_text(path)
    for _, lines, _ in text_blocks(path, 1 << 16):
        for raw in lines:
            line = raw.strip()
            if line and line[0] != "#":
                return line
    return None


def read_lines(path: Path) -> tuple[list[str], bool, int]:
    """Lines of a text file, whether the last one is unterminated, and its byte length.

    A leading UTF-8 byte order mark is skipped; NUL bytes (binary or zero-filled data) and
    invalid UTF-8 raise ``ValueError`` naming file and line.
    """
    raw = Path(path).read_bytes()
    nul = raw.find(b"\0")
    if nul >= 0:
        line = raw[:nul].count(b"\n") + 1
        raise FormatError(f"{path}:{line}: not a text recording (binary data: NUL byte)")
    if raw.startswith(b"\xef\xbb\xbf"):  # a UTF-8 byte order mark (Windows editors)
        raw = raw[3:]
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise FormatError(f"{path}:{line}: not UTF-8 text ({exc.reason})") from exc
    unterminated = bool(raw) and not raw.endswith(b"\n")
    del raw  # large files: never hold the bytes, the text and its lines at once
    lines = text.split("\n")
    del text
    if not unterminated and lines and lines[-1] == "":
        lines.pop()
    tail_bytes = len(lines[-1].encode()) if unterminated and lines else 0
    return lines, unterminated, tail_bytes
