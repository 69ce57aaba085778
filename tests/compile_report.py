"""Summarise a HINFNN_COMPILE_REPORT file (see conftest.py): the tests and files that spend the
most time, and how much of it is tracing, lowering and compiling JAX programs in the test's own
process, and the programs that took longest to trace, lower or compile (by their JAX names, summed
over the tests that compiled them). Usage: python tests/compile_report.py FILE [--top 30]"""

from __future__ import annotations

import argparse
import collections
import json


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("file")
    ap.add_argument("--top", type=int, default=30)
    args = ap.parse_args()
    rows = [json.loads(line) for line in open(args.file, encoding="utf-8") if line.strip()]
    keys = ("wall", "cpu", "trace", "lower", "compile", "programs", "cache_hits")
    by_file = collections.defaultdict(lambda: collections.Counter())
    for r in rows:
        f = r["test"].split("::")[0]
        for k in keys:
            by_file[f][k] += r.get(k, 0)
    head = f"{'wall s':>8} {'cpu s':>7} {'trace':>7} {'lower':>7} {'compile':>8} {'progs':>6} {'hits':>5}  "
    print(head + "file")
    for f, c in sorted(by_file.items(), key=lambda kv: -kv[1]["wall"]):
        print(f"{c['wall']:8.1f} {c['cpu']:7.1f} {c['trace']:7.1f} {c['lower']:7.1f} {c['compile']:8.1f} "
              f"{c['programs']:6d} {c['cache_hits']:5d}  {f}")
    total, cpu = sum(r["wall"] for r in rows), sum(r.get("cpu", 0) for r in rows)
    print(f"{total:8.1f} s ({cpu:.1f} s of CPU) in {len(rows)} tests (sum over workers)\n")
    print(head + "test")
    for r in sorted(rows, key=lambda r: -r["wall"])[:args.top]:
        print(f"{r['wall']:8.1f} {r.get('cpu', 0):7.1f} {r.get('trace', 0):7.1f} {r.get('lower', 0):7.1f} "
              f"{r.get('compile', 0):8.1f} "
              f"{r.get('programs', 0):6d} {r.get('cache_hits', 0):5d}  {r['test']}")
    named = collections.defaultdict(lambda: [0, 0.0, collections.Counter()])
    for r in rows:
        for span, program, seconds in r.get("named", ()):  # spans of 0.2 s or more (conftest.py)
            entry = named[(span, program)]
            entry[0] += 1
            entry[1] += seconds
            entry[2][r["test"].split("::")[0]] += seconds
    print(f"\n{'seconds':>8} {'times':>6}  span     program (the files that spent most on it)")
    for (span, program), (count, seconds, files) in sorted(named.items(), key=lambda kv: -kv[1][1])[:args.top]:
        where = ", ".join(f"{f.removeprefix('tests/')} {s:.0f}" for f, s in files.most_common(3))
        print(f"{seconds:8.1f} {count:6d}  {span:8s} {program}  ({where})")


if __name__ == "__main__":
    main()
