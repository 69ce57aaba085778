"""Before a long run: how much it stores, how long it takes, whether it fits in memory.

:func:`plan` estimates, from the step count, the stored fields (the shape of one record, traced
with ``jax.eval_shape``) and the number of runs, the bytes a command will hold and its wall time;
:func:`check` refuses (a :class:`ResourceError`, exit 2 from the CLI) when the memory would not
fit in what the machine has available, saying how to store less.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re

from .errors import ConfigError

#: What a hinfnn process holds besides the stored samples (JAX, XLA's programs), bytes.
BASE_BYTES = 600e6
#: Single-run speed used for the time estimate, steps per second (this project's 2-core machine:
#: 70,000 for the adaptive law, 100,000 for the others; a batch of B runs is up to 3x faster per
#: run-step). A rough figure: the progress bar's ETA is the measured one.
STEPS_PER_SECOND = 70_000.0


class ResourceError(ConfigError):
    """A command would need more memory than the machine has available."""


#: Environment variable that caps the memory hinfnn plans with (``8GB``, ``512MB``, ``2e9``).
ENV_MAX_MEMORY = "HINFNN_MAX_MEMORY"
_UNITS = {"": 1, "B": 1, "K": 1e3, "KB": 1e3, "M": 1e6, "MB": 1e6, "G": 1e9, "GB": 1e9, "T": 1e12, "TB": 1e12,
          "KIB": 2**10, "MIB": 2**20, "GIB": 2**30, "TIB": 2**40}


def parse_size(text: str) -> int:
    """``"8GB"`` -> 8e9, ``"512 MiB"``, ``"2e9"`` (bytes). ValueError for anything else."""
    m = re.fullmatch(r"\s*([0-9.]+(?:e[+-]?[0-9]+)?)\s*([A-Za-z]*)\s*", text)
    if not m or m.group(2).upper() not in _UNITS:
        raise ValueError(text)
    value = float(m.group(1)) * _UNITS[m.group(2).upper()]
    if not math.isfinite(value) or value <= 0:
        raise ValueError(text)
    return int(value)


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux ``MemAvailable``; else free pages),
    capped by the process's cgroup memory limit and by ``HINFNN_MAX_MEMORY`` when set, or None when
    the system does not say."""
    found = None
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    found = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    if found is None:
        try:
            found = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            found = None
    for limit_file in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = open(limit_file, encoding="ascii").read().strip()  # noqa: SIM115 - a one-line file
        except OSError:
            continue
        if text.isdigit():  # "max": no limit
            found = int(text) if found is None else min(found, int(text))
    cap = os.environ.get(ENV_MAX_MEMORY, "").strip()
    if cap:
        try:
            limit = parse_size(cap)
        except ValueError:
            raise ConfigError(f"must be a size such as 8GB, 512MB or 2e9, got {cap!r}", key=ENV_MAX_MEMORY) from None
        found = limit if found is None else min(found, limit)
    return found


def size(n: float) -> str:
    """Bytes for people: ``512 B``, ``473.5 kB``, ``1.2 MB``, ``38.4 GB``."""
    if n < 1000:
        return f"{n:.0f} B"
    for unit in ("kB", "MB", "GB", "TB"):
        n /= 1000
        if n < 1000 or unit == "TB":
            return f"{n:.1f} {unit}"
    return f"{n:.1f} TB"


def duration(seconds: float) -> str:
    """``45 s``, ``12 min``, ``3.4 h``, ``2.1 days``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    if seconds < 2 * 86400:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


@dataclasses.dataclass(frozen=True)
class Plan:
    """What a command will hold and take: ``runs`` runs of ``steps`` steps each group summed in
    ``total_steps``; ``samples`` stored per run (the longest), ``numbers`` float64 numbers per
    sample (the widest run), ``stored`` bytes of all stored samples, ``peak`` the estimated peak
    memory of the process (stored samples held twice while the files are written, plus the base),
    ``seconds`` a rough wall time."""

    runs: int
    total_steps: int
    samples: int
    numbers: int
    stored: float
    peak: float
    seconds: float
    interval: float  # seconds between stored samples

    def summary(self) -> str:
        """``1 run of 1,000,000 steps, storing 100,001 samples of 48 numbers each, needs about
        0.7 GB of memory and 14 s``."""
        one = self.runs == 1
        return (f"{self.runs} run{'' if one else 's'} of {self.total_steps // max(self.runs, 1):,} steps, storing "
                f"{self.samples:,} samples of {self.numbers} numbers each, need{'s' if one else ''} about "
                f"{size(self.peak)} of memory and {duration(self.seconds)}")


def plan(runs, *, fields=None, save_every: int | None = None, copies: float = 2.0) -> Plan:
    """The :class:`Plan` of simulating ``runs`` (:class:`hinfnn.sim.Run`), as
    :func:`hinfnn.sim.simulate_many` would with ``fields`` and ``save_every``. ``copies``: how
    many times the stored samples are held at the peak (2: the arrays and the file being
    written)."""
    from .sim.simulate import RunProgram

    groups: dict = {}
    for r in runs:
        groups.setdefault(r.group_key(), []).append(r)
    stored = 0.0
    total_steps = 0
    seconds = 0.0
    samples = numbers = 0
    interval = math.inf
    for items in groups.values():
        r = items[0]
        step_plan = r.plan(save_every)
        n_steps, every = step_plan.n_steps, step_plan.save_every
        shapes = RunProgram.record_shapes(r.plant, r.controller, r.reference, q0=r.q0, dt=r.dt,
                               control_period=r.control_period, fields=fields, limits=r.limits,
                               single=len(items) == 1,  # a group of one runs the single-run program
                               bookkeeping=r.bookkeeping)
        per_sample = sum(math.prod(shape) * dtype.itemsize for shape, dtype in shapes.values())
        n_samples = step_plan.samples
        stored += per_sample * n_samples * len(items)
        total_steps += n_steps * len(items)
        seconds += n_steps * len(items) / (STEPS_PER_SECOND * min(len(items), 3))
        samples = max(samples, n_samples)
        numbers = max(numbers, sum(math.prod(shape) for shape, _ in shapes.values()))
        interval = min(interval, every * r.dt)
    return Plan(runs=len(runs), total_steps=total_steps, samples=samples, numbers=numbers, stored=stored,
                peak=BASE_BYTES + copies * stored, seconds=seconds, interval=interval)


def check(p: Plan, *, available: int | None = None, alternatives=None, fields_option: bool = True) -> None:
    """Raise :class:`ResourceError` when ``p`` would not fit in the available memory, saying
    how to store less: a larger ``simulation.output_interval`` (the value that fits), and
    ``--fields metrics`` when it is enough (``alternatives()``: the plan with the metrics
    fields only, computed only when needed)."""
    available = available_memory() if available is None else available
    if available is None or p.peak <= available:
        return
    room = max(available - BASE_BYTES, 0.0)
    hints = []
    if room > 0:
        factor = (p.peak - BASE_BYTES) / room
        interval = _round_up(p.interval * factor * 1.25)
        hints.append(f"--set simulation.output_interval={interval}")
    if fields_option and alternatives is not None and room > 0:
        alt = alternatives()
        if alt.peak <= available:
            hints.append(f"--fields metrics (only what the metrics need: about {size(alt.peak)})")
    hints.append("a shorter simulation.t_final")
    raise ResourceError(
        f"{p.summary()}, but {size(available)} of memory is available; store less: " + ", or ".join(hints))


def _round_up(x: float) -> str:
    """A readable value ≥ x: 1, 2 or 5 times a power of ten."""
    if x <= 0 or not math.isfinite(x):
        return f"{x:g}"
    e = math.floor(math.log10(x))
    for m in (1, 2, 5, 10):
        if m * 10**e >= x * (1 - 1e-12):
            return f"{m * 10**e:g}"
    return f"{x:g}"
