"""The README's examples run as shown, on short horizons.

Every ```python block runs, in order, in one fresh Python process (as a user pasting them into one
session), with the horizons shortened (``t_final: 5.0`` / ``t_final=10.0`` -> 0.05 s). The robot
readings the robot-loop example leaves to the reader (``t, q, qd, F``) are given the paper
scenario's start values when no earlier block defines them.

Every command line of the ```sh blocks runs, in order, with
``--set simulation.t_final=0.05`` appended to ``hinfnn run`` / ``hinfnn reproduce`` (and
``--samples 2`` too to ``hinfnn sweep``, and ``--no-figures`` to the arm scenarios' ``hinfnn run``:
``hinfnn gallery`` draws the same arms' figures right after); a scenario
file a command names that does not exist is created as ``base = "paper"``. Skipped: ``make``
(the demo and the test suite itself) and usage synopses (lines with placeholders such as
``SCENARIO``, ``DIR``, ``KEY=VALUE`` or ``[--option]``). Each must exit 0 and print what a user
is told it prints (:data:`PRINTS`: the metrics table and the folder of a run, the report's path of
a study, the paths of the figures and tables drawn or exported, which must exist ...), and the
Python examples must print their two lines with numbers. The commands fall into three independent
groups (the arm scenarios, the sweeps, the rest), each run in its own fresh folder and process
(:func:`test_readme_shell_examples_run`).
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

import hinfnn as H

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
SRC = Path(H.__file__).resolve().parents[1]
HINFNN = Path(sys.executable).parent / "hinfnn"
SHORT = 0.05


def blocks(lang: str, text: str | None = None) -> list[str]:
    text = README.read_text(encoding="utf-8") if text is None else text
    return re.findall(rf"^```{lang}[ \t]*\n(.*?)^```", text, flags=re.M | re.S)


def shorten_python(code: str) -> str:
    """``t_final: 5.0``, ``"simulation.t_final": 5.0``, ``t_final=10.0`` -> the short horizon."""
    return re.sub(r"(t_final[\"']?\s*[:=]\s*)[0-9][0-9_.eE+-]*", rf"\g<1>{SHORT}", code)


def commands(block: str) -> list[str]:
    """The command lines of a shell block: continuations joined, comments dropped."""
    out, current = [], ""
    for line in block.splitlines():
        current += line.rstrip()
        if current.endswith("\\"):
            current = current[:-1] + " "
            continue
        words = shlex.split(current, comments=True) if current.strip() else []
        if words:
            out.append(words)
        current = ""
    return out


_PLACEHOLDER = re.compile(r"^\[|^[A-Z][A-Z_]{2,}(=[A-Z_]+)?$|\b(SCENARIO|DIR|KEY=VALUE|NAME|FILE)\b|\[--")


def runnable(words: list[str]) -> bool:
    if words[0] == "make":
        return False
    return not any(_PLACEHOLDER.search(w) for w in words[1:])


def adapt(words: list[str], cwd: Path, figures: bool = True) -> list[str]:
    if words[0] == "hinfnn" and len(words) > 1 and words[1] == "run" and not figures:
        words = words + ["--no-figures"]
    if words[0] == "hinfnn" and len(words) > 1 and words[1] in ("run", "reproduce", "gallery"):
        if words[1] == "run" and words[2].endswith(".toml") and not (cwd / words[2]).exists():
            (cwd / words[2]).write_text('base = "paper"\n')
        words = words + ["--set", f"simulation.t_final={SHORT}"]
    if words[0] == "hinfnn" and len(words) > 2 and words[1] == "sweep":
        words = words + ["--samples", "2", "--set", f"simulation.t_final={SHORT}"]
    if words[0] == "hinfnn":
        words = [str(HINFNN)] + words[1:]
    return words


def _env() -> dict:
    """The test session's compilation cache (conftest.py): programs other tests compiled are loaded,
    not compiled again (what a user's own cache does on their second command)."""
    return {**os.environ, "PYTHONPATH": str(SRC), "JAX_PLATFORMS": "cpu"}


def test_the_extraction_finds_the_examples():
    """The parser itself, on a made-up README."""
    text = "x\n```python\na = 1\nsimulate(t_final=10.0)\n```\n```sh\nmake demo  # no\nhinfnn run paper \\\n" \
           "  --set a=1   # yes\nhinfnn show DIR\nhinfnn run 'x y' --set 'k=[\"a\", \"b\"]'\n```\n"
    (py,) = blocks("python", text)
    assert shorten_python(py).endswith("simulate(t_final=0.05)\n")
    (sh,) = blocks("sh", text)
    cmds = commands(sh)
    assert [runnable(c) for c in cmds] == [False, True, False, True]
    assert cmds[1] == ["hinfnn", "run", "paper", "--set", "a=1"] and cmds[3][-1] == 'k=["a", "b"]'
    assert blocks("python") and blocks("sh"), "README.md has no examples?"


def test_readme_python_examples_run(tmp_path):
    code = "\n\n".join(shorten_python(b) for b in blocks("python"))
    preamble = (
        "import numpy as _np\n"
        "import hinfnn as _h\n"
        "_sc = _h.load_scenario('paper', check=False)\n"
        "t, q, qd, force = 0.0, _np.asarray(_sc.initial_q()), _np.zeros(2), _np.zeros(2)  # the robot's readings\n")
    script = tmp_path / "readme_examples.py"
    script.write_text(preamble + "\n" + code + "\n", encoding="utf-8")
    p = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=900,
                       env=_env())
    assert p.returncode == 0, f"README's Python examples fail:\n{p.stderr[-3000:]}"
    # the first example prints its metrics and the theorem's verdict (True: the adaptive law is dissipative)
    number = r"[0-9]+\.[0-9]+"
    assert re.search(rf"^RMS e_u1 = {number} m, RMS e_λ = {number}, J\(T\) = {number}$", p.stdout, re.M), p.stdout
    assert re.search(r"^dissipation inequality \(Theorem 1\) holds: True$", p.stdout, re.M), p.stdout


def _sh_commands():
    out = []
    for block in blocks("sh"):
        out += [c for c in commands(block) if runnable(c)]
    return out


#: Commands that depend on no other command (a fresh scenario name or output folder) start a new
#: group; the groups run as separate tests (so the two pytest-xdist workers share them), each
#: in one fresh Python process that calls the CLI's ``main`` once per command, as the shell would:
#: a program one command compiled is reused by the next one in memory (``hinfnn gallery`` after
#: ``hinfnn run ur5-table``), not traced, lowered and loaded again. The process sets the garbage
#: collector's thresholds as the ``hinfnn`` program does (``program_gc`` in hinfnn/cli.py; the
#: cli and sweep groups, pytest included, took 55.0 and 56.9 user-s instead of 57.4 and 59.2 with
#: Python's default).
#: The first command of the README runs as a real ``hinfnn`` process, so the console script is
#: checked too.
_ARMS = ("planar3-drum", "ur5-table", "ur5-sphere", "gallery")


def _groups() -> dict[str, list[list[str]]]:
    groups: dict[str, list[list[str]]] = {"cli": [], "arms": [], "sweep": []}
    for words in _sh_commands():
        name = "sweep" if words[1:2] == ["sweep"] else (
            "arms" if any(w in _ARMS for w in words[1:3]) else "cli")
        groups[name].append(words)
    return groups


_DRIVER = """
import contextlib, io, json, os, sys
from hinfnn.cli import program_gc
program_gc()  # as the hinfnn program does first (main(argv) called from Python does not)
from hinfnn.cli import main
done = []
for argv in json.loads(sys.argv[1]):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
    done.append({"argv": argv, "code": code, "out": out.getvalue(), "err": err.getvalue()[-500:]})
print(json.dumps(done))
"""

#: What each command of the README prints on its standard output (a regular expression, or several,
#: that must match, multi-line), by its verb (and ``--list`` for ``sweep``).
PRINTS = {
    "run": r"^run +status +did its job +RMS e_u1 .*\n-+\n(.*\n)+^results: (?P<folder>\S+)/ \(metrics\.json, trajectory\.npz, "
           r"scenario\.toml",
    "reproduce": r"^report: (?P<folder>\S+)/report\.md",
    "gallery": r"^report: (?P<folder>\S+)/report\.md",
    "design": r"^\w+: terms .*\n  gains: K_p .*\n(.*\n)*  P_p \[",
    "compare": r"^results: (?P<folder>\S+)/ \(compare\.md",
    "sweep": r"^controller +runs +invalid +simulated +bounded +held contact +did its job\n(.*\n)+^results: (?P<folder>\S+)/ "
             r"\(results\.parquet",
    "sweep --list": (r"^paper-uncertainty +\S", r"^paper-map +\S"),
    "keys": r"^plant\.contact\.stiffness +\S",
    "scenarios": r"^paper +\S.*\n(.*\n)*^ur5-table +\S",
    "show": r"^run +status +did its job +RMS e_u1 .*\n-+\n\S+ +(ok|stopped)(.*\n)+^design of ",
    "plot": r"^(?P<file>\S+\.png)$",
    "export": r"^(?P<file>\S+\.(csv|parquet))$",
    "cache": r"^compilation cache: ",
}


def check_prints(argv: list[str], out: str, cwd: Path) -> str | None:
    """Why the output of one command is not what the README says it prints (None: it is): the
    pattern of its verb matches, and the folder or files it names exist."""
    verb = "sweep --list" if argv[:1] == ["sweep"] and "--list" in argv else argv[0]
    patterns = PRINTS.get(verb)
    if patterns is None:
        return f"no expectation for `hinfnn {verb}` in PRINTS"
    for pattern in (patterns,) if isinstance(patterns, str) else patterns:
        found = re.search(pattern, out, re.M)
        if found is None:
            return f"does not print what it should ({pattern!r}):\n{out[-1500:]}"
        for key in ("folder", "file"):
            if key in found.groupdict() and not (cwd / found.group(key)).exists():
                return f"names {found.group(key)}, which does not exist"
    return None


def test_readme_commands_are_grouped_without_losing_one():
    groups = _groups()
    assert sum(len(g) for g in groups.values()) == len(_sh_commands())
    assert all(groups.values()) and groups["cli"][0][:2] == ["hinfnn", "keys"]


@pytest.mark.parametrize("group", ["cli", "arms", "sweep"])
def test_readme_shell_examples_run(tmp_path, group):
    import json

    cmds = _groups()[group]
    if group == "cli":
        assert any(c[:2] == ["hinfnn", "run"] for c in cmds)
        first, cmds = cmds[0], cmds[1:]
        p = subprocess.run(adapt(first, tmp_path), cwd=tmp_path, capture_output=True, text=True, timeout=300,
                           env=_env())
        assert p.returncode == 0, f"{shlex.join(first)}  ->  exit {p.returncode}: {p.stderr.strip()[-500:]}"
        why = check_prints(first[1:], p.stdout, tmp_path)
        assert why is None, f"{shlex.join(first)}  ->  {why}"
    argvs = [adapt(words, tmp_path, figures=group != "arms")[1:] for words in cmds]
    assert all(words[0] == "hinfnn" for words in cmds), cmds
    p = subprocess.run([sys.executable, "-c", _DRIVER, json.dumps(argvs)], cwd=tmp_path, capture_output=True,
                       text=True, timeout=1500, env=_env())
    assert p.returncode == 0, p.stderr[-3000:]
    failures = []
    for r in json.loads(p.stdout.strip().splitlines()[-1]):
        why = f"exit {r['code']}: {r['err'].strip()}" if r["code"] != 0 else check_prints(r["argv"], r["out"], tmp_path)
        if why:
            failures.append(f"hinfnn {' '.join(r['argv'])}  ->  {why}")
    assert not failures, "README commands that fail:\n" + "\n".join(failures)
