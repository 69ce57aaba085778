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
``SCENARIO``, ``DIR``, ``KEY=VALUE`` or ``[--option]``). Each must exit 0. The commands fall into
three independent groups (the arm scenarios, the sweeps, the rest), each run in its own fresh
folder and process (:func:`test_readme_shell_examples_run`).
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
        "t, q, qd, F = 0.0, _np.asarray(_sc.initial_q()), _np.zeros(2), _np.zeros(2)  # the robot's readings\n")
    script = tmp_path / "readme_examples.py"
    script.write_text(preamble + "\n" + code + "\n", encoding="utf-8")
    p = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=900,
                       env=_env())
    assert p.returncode == 0, f"README's Python examples fail:\n{p.stderr[-3000:]}"


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
failures = []
for argv in json.loads(sys.argv[1]):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
    if code != 0:
        failures.append(f"hinfnn {' '.join(argv)}  ->  exit {code}: {err.getvalue().strip()[-500:]}")
print(json.dumps(failures))
"""


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
    argvs = [adapt(words, tmp_path, figures=group != "arms")[1:] for words in cmds]
    assert all(words[0] == "hinfnn" for words in cmds), cmds
    p = subprocess.run([sys.executable, "-c", _DRIVER, json.dumps(argvs)], cwd=tmp_path, capture_output=True,
                       text=True, timeout=1500, env=_env())
    assert p.returncode == 0, p.stderr[-3000:]
    failures = json.loads(p.stdout.strip().splitlines()[-1])
    assert not failures, "README commands that fail:\n" + "\n".join(failures)
