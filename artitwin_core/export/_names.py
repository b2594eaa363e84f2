"""Safe names for links, joints and files: what a user typed must never escape the output folder."""

from __future__ import annotations

import re
import unicodedata

_UNSAFE = re.compile(r"[^A-Za-z0-9_]+")


def sanitize_name(name: str, fallback: str = "part") -> str:
    """An ASCII identifier ``[A-Za-z_][A-Za-z0-9_]*`` made from ``name``.

    Accents are folded (``"tür"`` -> ``"tur"``), every other run of characters outside
    ``[A-Za-z0-9_]`` (spaces, dots, slashes, other scripts) becomes one ``_``, so ``"../door 1"``
    gives ``"door_1"``; no path separator or ``..`` can survive. A name that starts with a digit gets
    a ``p_`` prefix (XML-ish identifiers); an empty result becomes ``fallback``.
    """
    folded = unicodedata.normalize("NFKD", str(name)).encode("ascii", "ignore").decode("ascii")
    out = _UNSAFE.sub("_", folded).strip("_")
    out = re.sub(r"_+", "_", out)[:64].strip("_")
    if not out:
        out = fallback
    if out[0].isdigit():
        out = "p_" + out
    return out


def unique_names(names: list[str], reserved: tuple[str, ...] = ()) -> list[str]:
    """Sanitised names, made unique (case-insensitively, as some file systems are) with ``_2``, ``_3``."""
    taken = {r.lower() for r in reserved}
    out = []
    for name in names:
        base = sanitize_name(name)
        cand, i = base, 2
        while cand.lower() in taken:
            cand, i = f"{base}_{i}", i + 1
        taken.add(cand.lower())
        out.append(cand)
    return out
