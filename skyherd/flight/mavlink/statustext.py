"""Long STATUSTEXT: split into 50-byte chunks (MAVLink 2 `id` / `chunk_seq`) and reassembled.

The MAVLink rule: `id` 0 means the text is complete in one message. Otherwise every chunk of
one text carries the same non-zero `id` and `chunk_seq` 0, 1, 2, ...; a NUL in the text field
(a chunk shorter than 50 bytes) marks the last chunk, so a text whose length is a multiple of
50 ends with an empty chunk. Texts longer than MAX_CHUNKS chunks are cut, ending with "...".
"""

from __future__ import annotations

from collections import OrderedDict

TEXT_LEN = 50  # bytes of text per STATUSTEXT
MAX_CHUNKS = 20  # longest text sent: 1000 bytes
MAX_PARTIAL = 16  # texts being reassembled at once (per assembler); the oldest is dropped
GAP = "[...]"  # stands for a chunk that never arrived


def split_text(text: str, text_id: int) -> list[tuple[int, int, bytes]]:
    """(id, chunk_seq, text bytes) for each STATUSTEXT carrying `text` (ASCII, '?' for the rest).

    `text_id` (1..65535) is used only when the text needs more than one message."""
    raw = text.encode("ascii", "replace")
    if len(raw) <= TEXT_LEN:
        return [(0, 0, raw)]
    if len(raw) > MAX_CHUNKS * TEXT_LEN - 1:
        raw = raw[: MAX_CHUNKS * TEXT_LEN - 4] + b"..."
    if not 0 < text_id < 65536:
        raise ValueError(f"text_id must be in [1, 65535], got {text_id}")
    parts = [raw[i : i + TEXT_LEN] for i in range(0, len(raw), TEXT_LEN)]
    if len(parts[-1]) == TEXT_LEN:
        parts.append(b"")  # the terminating NUL needs a chunk of its own
    return [(text_id, seq, p) for seq, p in enumerate(parts)]


class StatustextAssembler:
    """Reassembles chunked STATUSTEXT per sender and `id`.

    `feed(msg)` returns the whole text when it is complete (at once for `id` 0), else None.
    A chunk that never arrived shows as "[...]"; partial texts are bounded (MAX_PARTIAL, the
    oldest dropped), so a sender that never finishes a text costs nothing lasting."""

    def __init__(self, max_partial: int = MAX_PARTIAL):
        self.max_partial = max_partial
        self._partial: OrderedDict[tuple[int, int, int], dict[int, str]] = OrderedDict()
        self.dropped = 0  # partial texts evicted before their last chunk came

    def feed(self, msg) -> str | None:
        text = msg.text
        if isinstance(text, bytes | bytearray):
            text = bytes(text).split(b"\0", 1)[0].decode("ascii", "replace")
        text_id = getattr(msg, "id", 0)
        if not text_id:
            return text
        seq = getattr(msg, "chunk_seq", 0)
        if seq >= MAX_CHUNKS:
            return None
        key = (msg.get_srcSystem(), msg.get_srcComponent(), text_id)
        chunks = self._partial.get(key)
        if chunks is None:
            if len(self._partial) >= self.max_partial:
                self._partial.popitem(last=False)
                self.dropped += 1
            chunks = self._partial[key] = {}
        chunks[seq] = text
        if len(text) >= TEXT_LEN:
            return None  # not the last chunk
        del self._partial[key]
        return "".join(chunks.get(i, GAP) for i in range(seq + 1))
