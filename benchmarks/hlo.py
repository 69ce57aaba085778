"""Kernels per RK4 step, read off the text of a compiled simulation chunk (XLA's optimised HLO).

A chunk program is ENTRY → the scan over stored samples (a ``while`` with a known trip count; with
the ``record_blocks`` loop option, a scan over blocks of an inner scan over samples, two) → the loop
over the steps between two samples (a ``while`` whose trip count is traced) → with RK4's stages
rolled, the loop over the stages (a ``while`` with a known trip count). Every ``fusion``, ``dot``,
``custom-call`` (a LAPACK or library call), ``reduce``-family instruction and ``copy`` left in a
loop body is one kernel that XLA's CPU runtime launches on its own; a nested ``while`` counts its
body times its trip count, a ``conditional`` its largest branch (as if taken every time: an upper
bound, with that part reported apart). What is counted is the step loop's body (the steps after the
first of each sample), the steady state of a run.

Used by ``benchmarks/run.py`` (``kernels/step`` columns) and usable on a dump
(``XLA_FLAGS=--xla_dump_to=DIR``, ``*.cpu_after_optimizations.txt``) of any version of hinfnn.
"""

from __future__ import annotations

import re

_KERNEL = re.compile(r"=\s*[^=]*?\s(fusion|dot|custom-call|reduce|reduce-window|sort|copy|scatter|gather|"
                     r"convolution|transpose|dynamic-update-slice|dynamic-slice|concatenate)\(")
_WHILE = re.compile(r"\swhile\(.*?condition=%?([\w.\-]+), body=%?([\w.\-]+)(.*)$")
_COND = re.compile(r"\sconditional\(.*?branch_computations=\{([^}]*)\}")
_TRIP = re.compile(r'"known_trip_count":\{"n":"(\d+)"\}')


def computations(text: str) -> tuple[dict, str]:
    """{name: [instruction lines]} of an HLO module's text, and the ENTRY computation's name."""
    comps, entry, name, lines = {}, None, None, []
    for line in text.splitlines():
        m = re.match(r"^(ENTRY\s+)?%?([\w.\-]+)\s.*\{\s*$", line)
        if m and not line.startswith(" "):
            name, lines = m.group(2), []
            if m.group(1):
                entry = name
            continue
        if line.startswith("}") and name is not None:
            comps[name] = lines
            name = None
            continue
        if name is not None:
            lines.append(line)
    return comps, entry


def whiles(lines):
    for line in lines:
        m = _WHILE.search(line)
        if m:
            trip = _TRIP.search(line)
            yield m.group(1), m.group(2), int(trip.group(1)) if trip else None


_OP = re.compile(r"= f64\[([\d,]*)\]\S* (tanh|sine|cosine|divide|exponential|sqrt)\(")
#: An elementwise instruction: (its shape's dimensions, its operation).
ARITH = re.compile(r"= (?:f64|f32|pred|s32|s64)\[([\d,]*)\]\S* (add|subtract|multiply|divide|tanh|sine|cosine|"
                   r"sqrt|rsqrt|maximum|minimum|select|compare|negate|exponential|atan2|abs|power|log|and|or|"
                   r"not|clamp)\(")


def size(dims: str) -> int:
    """Values in a shape of dimensions ``dims`` ("6,256"; "" for a scalar)."""
    n = 1
    for d in dims.split(","):
        if d:
            n *= int(d)
    return n


_CALLS = re.compile(r"(?:calls|to_apply)=%?([\w.\-]+)")


def _ops(comps: dict, name: str, seen=()) -> dict:
    """Elementwise transcendental operations (values, not instructions) one execution of ``name``
    performs, through the computations it calls (fusions)."""
    out: dict = {}
    for line in comps.get(name, ()):
        m = _OP.search(line)
        if m:
            out[m.group(2)] = out.get(m.group(2), 0) + size(m.group(1))
        for callee in _CALLS.findall(line):
            if callee not in seen:
                for k, v in _ops(comps, callee, seen + (name,)).items():
                    out[k] = out.get(k, 0) + v
    return out


def kernels(comps: dict, name: str) -> int:
    """Kernels one execution of computation ``name`` launches (nested loops expanded)."""
    return _walk(comps, name)[0]


def _walk(comps: dict, name: str) -> tuple[int, int, dict, int]:
    """(kernels, library calls, transcendental operations, kernels in conditionals) one execution of
    computation ``name`` launches, nested loops expanded by their trip counts, a conditional by its
    largest branch (an upper bound: the record's branch of RK4's rolled stages runs at one stage of
    four, the sampled update's at one step of ``n_hold``); the last number is that branch part."""
    n, calls, ops, in_cond = 0, 0, {}, 0

    def add(o, times=1):
        for k, v in o.items():
            ops[k] = ops.get(k, 0) + times * v

    for line in comps.get(name, ()):
        if _WHILE.search(line):
            continue
        m = _COND.search(line)
        if m:
            branches = [_walk(comps, b.strip().lstrip("%")) for b in m.group(1).split(",")]
            big = max(branches, key=lambda b: b[0])
            n, calls, in_cond = n + big[0], calls + big[1], in_cond + big[0]
            add(big[2])
        elif _KERNEL.search(line):
            n += 1
            calls += " custom-call(" in line
            for callee in _CALLS.findall(line):
                add(_ops(comps, callee))
    for cond, body, trip in whiles(comps.get(name, ())):
        for part in (body, cond):
            k, c, o, b = _walk(comps, part)
            n, calls, in_cond = n + (trip or 1) * k, calls + (trip or 1) * c, in_cond + (trip or 1) * b
            add(o, trip or 1)
    return n, calls, ops, in_cond


def distinct(comps: dict, name: str) -> int:
    """Kernels compiled into computation ``name`` and the loops and conditionals it holds, each
    counted once however often it runs: the code a loop's iteration goes through (XLA's CPU runtime
    costs more per launch the more distinct kernels a loop holds; ``run.py --cases launch_floor``)."""
    n = 0
    for line in comps.get(name, ()):
        if _WHILE.search(line):
            continue
        m = _COND.search(line)
        if m:
            n += sum(distinct(comps, b.strip().lstrip("%")) for b in m.group(1).split(","))
        elif _KERNEL.search(line):
            n += 1
    for cond, body, _ in whiles(comps.get(name, ())):
        n += distinct(comps, body) + distinct(comps, cond)
    return n


def step_loop(comps: dict, entry: str) -> str | None:
    """The body of the loop over the steps between two samples: the first ``while`` below ENTRY,
    through the scans over stored samples (known trip counts), whose trip count is traced."""
    name = entry
    while True:
        loops = list(whiles(comps.get(name, ())))
        if not loops:
            return None
        _, body, trip = loops[0]
        if trip is None:
            return body
        name = body


def step_kernels(text: str) -> dict:
    """Per RK4 step of a compiled chunk (the body of :func:`step_loop`: the steps between two
    samples, with its nested loops, RK4's rolled stages, expanded): the kernels
    XLA's CPU runtime launches, how many distinct kernels they come from (:func:`distinct`), how
    many of them are library calls (``custom-call``), and the transcendental operations (tanh, sin,
    cos, divide, exp, sqrt: values computed). Conditionals count by their largest branch as if taken
    at every iteration; ``kernels_in_conditionals`` is that part (so ``kernels`` is an upper bound).
    """
    comps, entry = computations(text)
    body = step_loop(comps, entry)
    if body is not None:
        k, c, o, b = _walk(comps, body)
        return dict(kernels=k, distinct_kernels=distinct(comps, body), custom_calls=c,
                    elementwise_per_step=o, kernels_in_conditionals=b)
    return dict(kernels=None, distinct_kernels=None, custom_calls=None, elementwise_per_step={},
                kernels_in_conditionals=None)
