"""Comments of a G-code line: ``( )`` anywhere, ``;`` to the end of the line.

One lexical rule for the modules that look at a line's words without the full reader (refinement, feed words,
conversion): the words are what is left when the comments are blanked out, so every offset in the line stays.
"""

from __future__ import annotations

__all__ = ["comment_first_line", "split_gcode_comments"]


def split_gcode_comments(s: str, *, lenient: bool = False) -> tuple[str | None, list[str]]:
    """The line with its comments replaced by spaces (same length), and the comments' texts.

    A ``(`` that is not closed makes the line malformed: the body is None, unless ``lenient``, when the rest of
    the line is the comment.
    """
    out: list[str] = []
    texts: list[str] = []
    i, n = 0, len(s)
    while i < n:
        ch = s[i]
        if ch == "(":
            j = s.find(")", i + 1)
            if j < 0:
                if not lenient:
                    return None, texts
                j = n
            texts.append(s[i + 1:j])
            out.append(" " * (min(j + 1, n) - i))
            i = j + 1
            continue
        if ch == ";":
            texts.append(s[i + 1:])
            out.append(" " * (n - i))
            break
        out.append(ch)
        i += 1
    return "".join(out), texts


def comment_first_line(text: str, note: str, *, klartext: bool = False) -> str:
    """``note`` as a comment at the end of the first line that is neither blank nor ``%``; no line moves.

    Klartext: ``; note``. G-code: `` note`` after a line that already ends in a ``;`` comment (a ``;`` outside
    parentheses; one inside ``( )`` is comment text), else `` (note)``.
    """
    lines = text.split("\n")
    for i, line in enumerate(lines):
        body = line.rstrip("\r")
        if not body.strip() or body.strip() == "%":
            continue
        eol = line[len(body):]
        if klartext:
            lines[i] = f"{body} ; {note}{eol}"
        elif _has_semicolon_comment(body):
            lines[i] = f"{body} {note}{eol}"
        else:
            lines[i] = f"{body} ({note}){eol}"
        break
    return "\n".join(lines)


def _has_semicolon_comment(body: str) -> bool:
    """True when the line ends in a ``;`` comment (a ``;`` outside parentheses)."""
    depth = 0
    for ch in body:
        if ch == "(":
            depth += 1
        elif ch == ")":
            depth = max(depth - 1, 0)
        elif ch == ";" and depth == 0:
            return True
    return False
