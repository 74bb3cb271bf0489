"""Wording of counts in what ilcnc prints: "1 iteration", "2 iterations" (issue 23 item 8).

One helper, so that every count a user reads agrees with its noun; the messages that end in JSON and
``state.json`` use it too (their text is for people, their numbers are separate fields).
"""

from __future__ import annotations

__all__ = ["plural"]

#: Nouns whose plural is not the singular plus "s".
_IRREGULAR = {"axis": "axes"}


def plural(n: int, noun: str, many: str | None = None) -> str:
    """``n`` and ``noun`` in the number ``n`` asks for.

    Parameters
    ----------
    n : int
        The count (0 and numbers other than 1 take the plural).
    noun : str
        The singular ("iteration", "G01 command").
    many : str, optional
        The plural when it is not ``noun + "s"`` nor in the small table of irregular words.

    Returns
    -------
    str
        ``"1 iteration"``, ``"3 iterations"``, ``"0 iterations"``.
    """
    if n == 1:
        return f"{n} {noun}"
    if many is None:
        head, _, last = noun.rpartition(" ")
        many = (head + " " if head else "") + _IRREGULAR.get(last, last + "s")
    return f"{n} {many}"
