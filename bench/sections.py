"""BENCHMARKS.md's sections: a study's section written in place, or before the profiling notes."""

from __future__ import annotations

__all__ = ["splice_section"]


def splice_section(text: str, title: str, part: list[str]) -> str:
    """``text`` (BENCHMARKS.md) with the section headed ``title`` replaced by ``part``'s lines.

    The section runs to the next ``## `` heading; a section not yet there goes before
    "## What changed after profiling", or at the end.
    """
    block = "\n".join(part).rstrip("\n") + "\n"
    lines = text.split("\n")
    if title in lines:
        i = lines.index(title)
        j = next((k for k in range(i + 1, len(lines)) if lines[k].startswith("## ")),
                 len(lines))
        return "\n".join(lines[:i]) + "\n" + block + "\n" + "\n".join(lines[j:])
    anchor = next((k for k, ln in enumerate(lines)
                   if ln.startswith("## What changed after profiling")), None)
    if anchor is None:
        return text.rstrip("\n") + "\n\n" + block
    return "\n".join(lines[:anchor]) + "\n" + block + "\n" + "\n".join(lines[anchor:])
