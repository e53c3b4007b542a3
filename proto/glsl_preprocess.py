"""The GLSL preprocessor of ``proto/glsl`` in Python: the same contract as the viewer's
``web/src/renderer/preprocess.js`` (proto/glsl/README.md, "Preprocessor contract"):

1. the output starts with the target's version line — ``"desktop"``: ``#version 330`` (moderngl, GLSL 3.30
   core), ``"webgl2"``: ``#version 300 es`` and the ``precision highp`` lines — then ``#define KILN_DESKTOP 1``
   or ``#define KILN_WEBGL2 1``, then the caller's defines (``False``/``None`` skipped, ``True`` → a bare
   ``#define NAME``), then the expanded source;
2. ``#include "file.glsl"`` is replaced by that file (relative to the folder), recursively, at most once per
   program; an include cycle is an error;
3. ``#include "@slot"`` is replaced by the file bound to the slot (``slots={"mode": "mode_ddgi.glsl"}``);
4. a ``#version`` line inside a file is an error, so is an unknown file or an unbound slot;
5. a line map (output line i + 1 → (file, line)) so compile errors name the file and line
   (:func:`format_compile_errors`).

Pure: sources come from a folder (default ``proto/glsl``) or a mapping file name → text.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

__all__ = ["GLSL_DIR", "ShaderSourceError", "Preprocessed", "preprocess", "load_sources", "format_compile_errors"]

GLSL_DIR = Path(__file__).resolve().parent / "glsl"

TARGETS = {
    "webgl2": ["#version 300 es", "precision highp float;", "precision highp int;", "precision highp sampler2D;",
               "precision highp sampler3D;", "precision highp usampler3D;", "#define KILN_WEBGL2 1"],
    "desktop": ["#version 330", "#define KILN_DESKTOP 1"],
}

_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"\s*(//.*)?$')
_VERSION = re.compile(r"^\s*#\s*version\b")


class ShaderSourceError(ValueError):
    """A malformed shader source: unknown file or slot, include cycle, a #version line in a file."""


@dataclass
class Preprocessed:
    code: str
    line_map: list[tuple[str, int]]  # line_map[i] = (file, line) of output line i + 1


def load_sources(folder: str | Path = GLSL_DIR) -> dict[str, str]:
    """Every ``*.glsl`` file of ``folder`` as a mapping file name → text."""
    return {p.name: p.read_text(encoding="utf-8") for p in sorted(Path(folder).glob("*.glsl"))}


def preprocess(entry: str, sources: Mapping[str, str] | None = None, *, target: str = "desktop",
               slots: Mapping[str, str] | None = None, defines: Mapping[str, object] | None = None) -> Preprocessed:
    """Expand ``entry`` for ``target`` (``"desktop"`` or ``"webgl2"``); see the module doc."""
    header = TARGETS.get(target)
    if header is None:
        raise ShaderSourceError(f"unknown shader target {target}")
    sources = load_sources() if sources is None else sources
    slots = dict(slots or {})
    out: list[str] = []
    line_map: list[tuple[str, int]] = []
    for line in header:
        out.append(line)
        line_map.append(("<header>", 0))
    for name, value in (defines or {}).items():
        if value is False or value is None:
            continue
        out.append(f"#define {name}" if value is True else f"#define {name} {value}")
        line_map.append(("<defines>", 0))
    included: set[str] = set()

    def expand(file: str, chain: list[str]) -> None:
        if file in chain:
            raise ShaderSourceError(f"include cycle: {' -> '.join([*chain, file])}")
        if file in included:
            return
        text = sources.get(file)
        if text is None:
            where = f" (included from {chain[-1]})" if chain else ""
            raise ShaderSourceError(f"unknown shader file {file}{where}")
        included.add(file)
        for i, line in enumerate(re.split(r"\r?\n", text)):
            if _VERSION.match(line):
                raise ShaderSourceError(f"{file}:{i + 1}: #version belongs to the preprocessor")
            m = _INCLUDE.match(line)
            if not m:
                out.append(line)
                line_map.append((file, i + 1))
                continue
            tgt = m.group(1)
            if tgt.startswith("@"):
                bound = slots.get(tgt[1:])
                if not bound:
                    raise ShaderSourceError(f"{file}:{i + 1}: slot {tgt} is not bound")
                tgt = bound
            expand(tgt, [*chain, file])

    expand(entry, [])
    return Preprocessed("\n".join(out) + "\n", line_map)


def format_compile_errors(log: str, pre: Preprocessed, context: int = 2) -> str:
    """A compile log with each error's origin (file:line) and numbered source lines around it. Accepts the
    Mesa/ANGLE form ``0:LINE(COL): error: …`` and the ``ERROR: 0:LINE: …`` form."""
    lines = pre.code.split("\n")
    parts = []
    for entry in str(log).splitlines():
        m = (re.match(r"^\s*(?:ERROR|WARNING):\s*\d+:(\d+):\s*(.*)$", entry)
             or re.match(r"^\s*\d+:(\d+)(?:\(\d+\))?:\s*(.*)$", entry))
        if not m:
            if entry.strip():
                parts.append(entry.strip())
            continue
        n = int(m.group(1))
        origin = pre.line_map[n - 1] if 0 < n <= len(pre.line_map) else None
        parts.append(f"{origin[0]}:{origin[1] if origin else n}: {m.group(2)}" if origin else f"line {n}: {m.group(2)}")
        for k in range(max(1, n - context), min(len(lines), n + context) + 1):
            parts.append(f"{'>' if k == n else ' '}{k:5d} | {lines[k - 1]}")
    return "\n".join(parts)
