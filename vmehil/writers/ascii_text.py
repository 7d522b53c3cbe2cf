"""Text for 7-bit lines: serial terminals and MAVLink STATUSTEXT, where a UTF-8 "²" or "…" turns
into "?" (MAVProxy) or mojibake (a raw terminal). One transliteration table for every such edge."""

from __future__ import annotations

import unicodedata

#: what the project's messages use, spelled the way an engineer would type it
_TABLE = {
    "²": "^2", "³": "^3", "…": "...", "—": "-", "–": "-", "−": "-", "←": "<-", "→": "->", "↔": "<->",
    "≤": "<=", "≥": ">=", "≠": "!=", "≈": "~", "±": "+/-", "×": "x", "·": "*", "÷": "/", "°": " deg",
    "µ": "u", "μ": "u", "Ω": "ohm", "ω": "w", "θ": "theta", "Δ": "d", "τ": "tau", "‖": "||",
    "‘": "'", "’": "'", "“": '"', "”": '"', "√": "sqrt", "∞": "inf", "⁻¹": "^-1", "¹": "^1",
}
_TRANS = str.maketrans({k: v for k, v in _TABLE.items() if len(k) == 1})


def to_ascii(text: str) -> str:
    """``text`` in printable ASCII: the table above, then accents dropped (é → e), then ``?``."""
    if text.isascii():
        return text
    text = text.replace("⁻¹", "^-1").translate(_TRANS)
    if text.isascii():
        return text
    decomposed = unicodedata.normalize("NFKD", text)
    return "".join(c if c.isascii() else ("" if unicodedata.combining(c) else "?") for c in decomposed)
