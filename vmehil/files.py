"""Atomic file writes: temporary file in the same folder, fsync, rename (POSIX atomic)."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any


def write_atomic(path: str | Path, data: bytes | str, *, keep_previous: bool = False) -> Path:
    """Write ``data`` to ``path`` so readers see the old file or the new one, never a mix.

    With ``keep_previous`` the old file is kept as ``<name>.prev`` (hard link) first.
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    raw = data.encode() if isinstance(data, str) else data
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(raw)
            f.flush()
            os.fsync(f.fileno())
        if keep_previous and p.exists():
            prev = p.with_name(p.name + ".prev")
            if prev.exists():
                prev.unlink()
            os.link(p, prev)
        os.replace(tmp, p)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    try:
        dfd = os.open(p.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError:
        pass
    return p


def write_json(path: str | Path, obj: Any) -> Path:
    """Atomically write ``obj`` as indented JSON (NaN/inf are written as null)."""
    return write_atomic(path, json.dumps(_clean(obj), indent=2) + "\n")


def _clean(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if obj == obj and obj not in (float("inf"), float("-inf")) else None
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    if hasattr(obj, "item") and callable(obj.item):  # numpy scalars
        return _clean(obj.item())
    return obj


def save_figure(fig: Any, path: str | Path, formats: tuple[str, ...] = ("png",)) -> list[Path]:
    """Save a matplotlib figure atomically in each format (``path`` without suffix)."""
    import io

    out = []
    for fmt in formats:
        buf = io.BytesIO()
        fig.savefig(buf, format=fmt, dpi=110, bbox_inches="tight")
        out.append(write_atomic(Path(f"{path}.{fmt}"), buf.getvalue()))
    return out
