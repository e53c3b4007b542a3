"""Quality gates for build tools: ``kiln bake ... --fail-on 'mask_normalized.leak > 0.05'`` and ``--junit FILE``.

Grammar (one gate per ``--fail-on``; repeat the option for more)::

    gate    := metric op number
    metric  := a metric name of the manifest, [A-Za-z0-9_.*-]+; "*" matches any characters (fnmatch), so
               "*.leak" is every mode's leak
    op      := ">" | ">=" | "<" | "<=" | "==" | "!="
    number  := a decimal number: 0.05, -1, 2.5e-3

A gate **fails** when its comparison holds for a metric it names (it says what to fail on), and also when it
names no metric of the bake (a typo, or evaluate off: a gate that cannot be checked never passes silently).
A pattern is checked against every metric it matches (``<metric>_stderr`` only when the pattern ends so). Each
value is shown with its standard error (the reference's noise, ``<metric>_stderr``) where the bake has one, and a
verdict within :data:`NOISE_SIGMAS` standard errors of the threshold says so: the gate still decides on the value,
but the user learns that the reference's noise could flip it (a mode whose error is below that noise, see
docs/architecture.md "Evaluate").

Metrics (:func:`manifest_metrics`; what the server's catalog holds for a bake): the evaluate stage's
``stats.metrics`` — ``<mode>.rmse``, ``<mode>.leak``, ``<mode>.mean_ratio``, ``<mode>.indirect_relative_rmse``,
``<mode>.indirect_excess`` (each with ``<...>_stderr``), ``<mode>.region.<name>.mean_ratio``, ``<mode>.pass_ms``,
``<mode>.texture_bytes``, ... (workers/stages/evaluate.py) — plus ``stage_seconds.<stage>`` and
``artifact_bytes``.

JUnit XML (:func:`junit_xml`): a suite ``kiln.gates`` with one test case per gate (failed with the offending
values) and a suite ``kiln.modes`` with one test case per evaluated GI mode (failed when a gate on one of its
metrics failed; its metrics in ``system-out``).
"""
from __future__ import annotations

import fnmatch
import math
import operator
import re
from dataclasses import dataclass, field
from xml.etree import ElementTree as ET

from proto.stages import manifest_metrics

__all__ = ["Gate", "GateError", "parse_gate", "parse_gates", "manifest_metrics", "check", "junit_xml", "GRAMMAR"]

GRAMMAR = "METRIC OP NUMBER, OP one of > >= < <= == != (e.g. 'mask_normalized.leak > 0.05'; '*' matches any text)"
_OPS = {">=": operator.ge, "<=": operator.le, "==": operator.eq, "!=": operator.ne, ">": operator.gt,
        "<": operator.lt}
_RE = re.compile(r"^\s*(?P<metric>[A-Za-z0-9_.*\-]+)\s*(?P<op>>=|<=|==|!=|>|<)\s*"
                 r"(?P<num>[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)\s*$")


NOISE_SIGMAS = 2.0
"""A gate's verdict on a metric within this many of its standard errors (the reference's noise) of the threshold is
called out as uncertain in its description (it still passes or fails on the value)."""


class GateError(ValueError):
    """A gate that does not parse (the message quotes it and the grammar)."""


@dataclass
class Gate:
    text: str
    metric: str
    op: str
    value: float
    # filled by check():
    matched: dict = field(default_factory=dict)     # metric -> value
    failing: dict = field(default_factory=dict)     # metric -> value where the comparison holds
    stderr: dict = field(default_factory=dict)      # metric -> its standard error (``<metric>_stderr``), if any

    @property
    def failed(self) -> bool:
        return bool(self.failing) or not self.matched

    @property
    def uncertain(self) -> list[str]:
        """The matched metrics within :data:`NOISE_SIGMAS` standard errors of the threshold: the reference's own
        noise could change the verdict (more reference paths, another seed)."""
        return [k for k, v in self.matched.items()
                if self.stderr.get(k) and abs(v - self.value) < NOISE_SIGMAS * self.stderr[k]]

    def show(self, k: str, v: float) -> str:
        """``metric = value ± stderr`` (the standard error where the bake has one)."""
        se = self.stderr.get(k)
        return f"{k} = {v:.6g}" + (f" ± {se:.2g}" if se else "")

    def describe(self) -> str:
        if not self.matched:
            return f"{self.text}: no metric {self.metric!r} in this bake (is evaluate enabled?)"
        near = self.uncertain
        note = (f"; within {NOISE_SIGMAS:g} standard errors of {self.value:g}: {', '.join(near)} (the reference's "
                f"noise could change this verdict)") if near else ""
        if self.failing:
            vals = ", ".join(self.show(k, v) for k, v in self.failing.items())
            return f"{self.text}: {vals}{note}"
        vals = ", ".join(self.show(k, v) for k, v in self.matched.items())
        return f"{self.text}: passed ({vals}){note}"


def parse_gate(text: str) -> Gate:
    m = _RE.match(text or "")
    if not m:
        raise GateError(f"cannot read the gate {text!r}: expected {GRAMMAR}")
    v = float(m["num"])
    if not math.isfinite(v):
        raise GateError(f"the gate {text!r} compares with a non-finite number")
    return Gate(text=text.strip(), metric=m["metric"], op=m["op"], value=v)


def parse_gates(texts) -> list[Gate]:
    return [parse_gate(t) for t in (texts or [])]


def check(gates: list[Gate], metrics: dict[str, float]) -> list[Gate]:
    """Evaluate each gate against ``metrics`` (fills ``matched`` and ``failing``); returns the failed gates."""
    for g in gates:
        names = [k for k in metrics if fnmatch.fnmatchcase(k, g.metric)] if any(c in g.metric for c in "*?[") \
            else ([g.metric] if g.metric in metrics else [])
        names = [k for k in names if not k.endswith("_stderr") or g.metric.endswith("_stderr")]
        g.matched = {k: metrics[k] for k in sorted(names)}
        g.stderr = {k: metrics[f"{k}_stderr"] for k in g.matched if f"{k}_stderr" in metrics}
        g.failing = {k: v for k, v in g.matched.items() if _OPS[g.op](v, g.value)}
    return [g for g in gates if g.failed]


def _modes(manifest: dict) -> list[str]:
    for s in manifest.get("stages", []):
        if s["name"] == "evaluate":
            return list((s.get("stats") or {}).get("modes") or [])
    return []


def junit_xml(gates: list[Gate], manifest: dict, metrics: dict[str, float] | None = None) -> bytes:
    """JUnit XML of checked gates (module doc)."""
    metrics = manifest_metrics(manifest) if metrics is None else metrics
    bake = manifest.get("bake_id") or (manifest.get("scene") or {}).get("id", "")[:12]
    root = ET.Element("testsuites", name="kiln")
    suite = ET.SubElement(root, "testsuite", name="kiln.gates", tests=str(len(gates)),
                          failures=str(sum(g.failed for g in gates)), errors="0")
    for g in gates:
        case = ET.SubElement(suite, "testcase", classname="kiln.gates", name=g.text, time="0")
        if g.failed:
            f = ET.SubElement(case, "failure", type="gate" if g.matched else "missing_metric",
                              message=g.describe())
            f.text = g.describe()
        ET.SubElement(case, "system-out").text = "\n".join(g.show(k, v) for k, v in g.matched.items())
    modes = _modes(manifest)
    msuite = ET.SubElement(root, "testsuite", name="kiln.modes", tests=str(len(modes)), errors="0")
    n_failed = 0
    for m in modes:
        case = ET.SubElement(msuite, "testcase", classname="kiln.modes", name=m, time="0")
        bad = [g for g in gates if any(k.startswith(f"{m}.") for k in g.failing)]
        if bad:
            n_failed += 1
            text = "; ".join(g.describe() for g in bad)
            ET.SubElement(case, "failure", type="gate", message=text).text = text
        own = {k: v for k, v in metrics.items() if k.startswith(f"{m}.")}
        ET.SubElement(case, "system-out").text = "\n".join(f"{k} = {v:.6g}" for k, v in sorted(own.items()))
    msuite.set("failures", str(n_failed))
    for s in (suite, msuite):
        props = ET.Element("properties")
        ET.SubElement(props, "property", name="bake", value=str(bake))
        s.insert(0, props)
    root.set("tests", str(len(gates) + len(modes)))
    root.set("failures", str(sum(g.failed for g in gates) + n_failed))
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8") + b"\n"
