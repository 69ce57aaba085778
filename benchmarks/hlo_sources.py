"""Where a compiled chunk's kernels and arithmetic come from: the kernels of one loop body of the
optimised HLO (``benchmarks/hlo.py``), each with the elementwise operations it performs and the
hinfnn function that wrote most of its instructions (read off the module's stack-frame tables).

    python benchmarks/hlo_sources.py CHUNK.hlo [--loop stage|step] [--top N]

``CHUNK.hlo`` is the text of a compiled chunk (``benchmarks/run.py``'s ``chunk_text``, or XLA's
``*.cpu_after_optimizations.txt`` dump). ``--loop stage`` (default) is the body of RK4's rolled
stages (arms), ``step`` the body of the steps between two samples. It prints the kernels with the
most operations per output value (a product copied into several consumers shows up there: that
is how the need for ``la.stored`` was found), then kernels and operations per function.

The operations are counted per HLO instruction at its full shape: a kernel that slices a fused
product is charged the whole product, although XLA computes only the elements it reads. The
counts rank the kernels; they are not a measure of the time.
"""

from __future__ import annotations

import argparse
import collections
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import hlo  # noqa: E402

_CALLS = hlo._CALLS  # the computations an instruction calls (fusions, reductions)
#: Helpers of hinfnn's small algebra: a kernel is attributed to the first caller outside them.
HELPERS = re.compile(r"^(mm|store|stored|_stored|chol|chol_solve|_stored_columns|cross|dot|add|sub|scale|matvec|"
                     r"matmul|crm|crf|inertia_apply|_masked_sum|prefix|suffix|assemble|sdot|keep|grid_stack|table|"
                     r"table_column|prefix_sums|sincos|runtime_one)(\.<locals>.*)?$")


def _table(lines: list, name: str) -> dict:
    """{id: text} of one of the module's tables (FileNames, FunctionNames, FileLocations, StackFrames)."""
    try:
        i = lines.index(name)
    except ValueError:
        return {}
    out = {}
    for line in lines[i + 1:]:
        if not line[:1].isdigit():
            break
        k, v = line.split(" ", 1)
        out[int(k)] = v
    return out


def frames(text: str):
    """A function: stack frame id → [(file, function, line), ...] innermost first."""
    lines = text.splitlines()
    files = {k: v.strip('"').split("hinfnn/")[-1] for k, v in _table(lines, "FileNames").items()}
    funcs = {k: v.strip('"') for k, v in _table(lines, "FunctionNames").items()}
    locs = {}
    for k, v in _table(lines, "FileLocations").items():
        m = re.search(r"file_name_id=(\d+) function_name_id=(\d+) line=(\d+)", v)
        locs[k] = (files.get(int(m.group(1)), "?"), funcs.get(int(m.group(2)), "?"), int(m.group(3)))
    parent = {}
    for k, v in _table(lines, "StackFrames").items():
        m = re.search(r"file_location_id=(\d+)(?: parent_frame_id=(\d+))?", v)
        parent[k] = (int(m.group(1)), int(m.group(2)) - 1 if m.group(2) else None)  # printed one-based

    def chain(fid):
        out, seen = [], set()
        while fid and fid in parent and fid not in seen:
            seen.add(fid)
            loc, fid = parent[fid]
            out.append(locs.get(loc, ("?", "?", 0)))
        return out
    return chain


def kernel_table(text: str, loop: str = "stage") -> list:
    """[(operations, output values, shape, source), ...] of the kernels of one loop body."""
    comps, entry = hlo.computations(text)
    chain = frames(text)
    memo = {}

    def ops(name):
        if name not in memo:
            n = 0
            for line in comps.get(name, ()):
                m = hlo.ARITH.search(line)
                if m:
                    n += hlo.size(m.group(1))
                n += sum(ops(c) for c in _CALLS.findall(line))
            memo[name] = n
        return memo[name]

    body = hlo.step_loop(comps, entry)
    if loop == "stage":
        inner = list(hlo.whiles(comps[body]))
        if not inner:
            raise SystemExit("this chunk has no rolled RK4 stages (a 2-joint arm?): use --loop step")
        body = inner[0][1]
    rows = []
    for line in comps[body]:
        if not hlo._KERNEL.search(line):
            continue
        calls = _CALLS.findall(line)
        shape = re.search(r"= (\(.*?\)|\S+) ", line).group(1)
        out = sum(hlo.size(m) for m in re.findall(r"\[([\d,]*)\]", shape))
        src = collections.Counter()
        for c in calls:
            for x in comps.get(c, ()):
                m = re.search(r"stack_frame_id=(\d+)", x)
                if m:
                    outer = [f"{f}:{fn}" for f, fn, _ in chain(int(m.group(1))) if not HELPERS.match(fn)]
                    src[outer[0] if outer else "?"] += 1
        if not calls:
            src[re.search(r" ([a-z-]+)\(", line).group(1) + " (no fusion)"] += 1
        rows.append((sum(ops(c) for c in calls), out, shape[:28], src.most_common(1)[0][0] if src else "?"))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("hlo", help="text of a compiled chunk")
    ap.add_argument("--loop", choices=("stage", "step"), default="stage")
    ap.add_argument("--top", type=int, default=25)
    a = ap.parse_args(argv)
    rows = kernel_table(Path(a.hlo).read_text(), a.loop)
    print(f"{len(rows)} kernels, {sum(r[0] for r in rows):,} operations, {sum(r[1] for r in rows):,} output values")
    print(f"\n{'ops':>7} {'out':>5} {'ops/out':>8}  shape / source")
    for r in sorted(rows, key=lambda r: -r[0] / max(r[1], 1))[:a.top]:
        print(f"{r[0]:7d} {r[1]:5d} {r[0] / max(r[1], 1):8.1f}  {r[2]:28s} {r[3]}")
    by_ops, by_n = collections.Counter(), collections.Counter()
    for r in rows:
        by_ops[r[3]] += r[0]
        by_n[r[3]] += 1
    print(f"\n{'kernels':>7} {'ops':>7}  function")
    for k, n in by_n.most_common(a.top):
        print(f"{n:7d} {by_ops[k]:7d}  {k}")


if __name__ == "__main__":
    main()
