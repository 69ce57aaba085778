"""The step plan of a run: how many steps, how often the controller samples, which steps are
stored and how the compiled program walks through them in chunks. One place computes it; the
simulator, the memory plan (:mod:`hinfnn.resources`), the sweep planner and the study use it.
"""

from __future__ import annotations

import dataclasses
import math

from ..errors import ConfigError, is_integer, is_real

#: Default interval between stored samples, s (``simulation.output_interval``).
DEFAULT_SAVE_INTERVAL = 1e-3
#: Steps per compiled chunk, about: a run is a Python loop over chunks of one jit-compiled program
#: (progress, Ctrl-C and one compilation for every horizon), never a loop over time steps.
CHUNK_STEPS = 2000
#: Record slots of a single run's chunk program (:meth:`StepPlan.chunk`).
SINGLE_RECORDS = 200


@dataclasses.dataclass(frozen=True)
class StepPlan:
    """``n_steps`` steps of ``dt`` (t_final = n_steps · dt); a stored sample every ``save_every``
    steps (t = 0, …, t_final: :attr:`samples` of them); under sampled control the controller runs
    every ``n_hold`` steps with zero-order hold between (0: continuous control, the controller at
    every RK4 stage)."""

    n_steps: int
    dt: float
    save_every: int
    n_hold: int = 0

    @classmethod
    def make(cls, t_final, dt, *, control_period=None, save_interval=None, save_every=None,
             discrete: bool = False) -> "StepPlan":
        """The plan of a run, checked: ConfigError naming the scenario key when ``dt`` does not
        divide ``t_final``, the control period is not a whole number of steps or does not divide
        the horizon, or ``save_every`` does not divide the steps. ``save_every`` None: the
        largest divisor s of the step count with s · dt ≤ ``save_interval`` (default
        :data:`DEFAULT_SAVE_INTERVAL`), so samples stay uniform and the last falls on t_final. A
        ``discrete`` plant (one that steps itself) always runs the sampled-data path, at least
        every step."""
        for name, v in (("t_final", t_final), ("dt", dt)):
            if not (is_real(v) and math.isfinite(v) and v > 0):
                raise ConfigError(f"must be a finite number > 0, got {v!r}", key=f"simulation.{name}")
        n_steps = round(t_final / dt)
        if n_steps < 1 or abs(n_steps * dt - t_final) > 1e-9 * max(1.0, t_final):
            raise ConfigError(f"t_final = {t_final:g} is not a whole number of steps dt = {dt:g}",
                              key="simulation.t_final")
        if save_every is None:
            save_every = save_every_for(n_steps, dt, DEFAULT_SAVE_INTERVAL if save_interval is None else save_interval)
        if not (is_integer(save_every) and save_every >= 1 and n_steps % save_every == 0):
            raise ConfigError(f"must be a whole number of steps dividing the {n_steps} steps, got {save_every!r}",
                              key="simulation.output_interval")
        save_every = int(save_every)
        n_hold = 0
        if control_period is None and discrete:
            control_period = dt
        if control_period is not None:
            n_hold = round(control_period / dt)
            if n_hold < 1 or abs(n_hold * dt - control_period) > 1e-9 * control_period:
                raise ConfigError(f"control period {control_period:g} must be a whole multiple of dt = {dt:g}",
                                  key="simulation.control_period")
            if n_steps % n_hold:
                raise ConfigError(f"control period {control_period:g} s does not divide t_final = {t_final:g} s "
                                  f"({n_steps} steps of dt = {dt:g} s are not a whole number of {n_hold}-step "
                                  "periods)", key="simulation.control_period")
        return cls(n_steps=n_steps, dt=float(dt), save_every=save_every, n_hold=n_hold)

    @property
    def sampled(self) -> bool:
        """Whether the controller runs at a fixed period with zero-order hold."""
        return self.n_hold > 0

    @property
    def t_final(self) -> float:
        return self.n_steps * self.dt

    @property
    def samples(self) -> int:
        """Stored samples, t = 0 … t_final."""
        return self.n_steps // self.save_every + 1

    @property
    def interval(self) -> float:
        """Seconds between stored samples."""
        return self.save_every * self.dt

    def chunk(self, batched: bool) -> tuple[int, int]:
        """(record slots of the compiled chunk program, samples a chunk takes).

        A single run has one program whatever it stores and however often: :data:`SINGLE_RECORDS`
        slots, of which a chunk fills about :data:`CHUNK_STEPS` steps' worth (200 for 1–10 steps
        between samples, 182 for 11, 20 for 100, 1 from 2,000 on); the slots it leaves run no step.
        The count is a traced argument, so a new output interval, dt, horizon or stored fields
        reuse the compiled program. An unused slot runs no step (in the sampled mode it still
        evaluates the controller's sample, as the padding records past t_final do). A batch keeps
        a program per chunk size (:func:`records_per_chunk`): its records are B times larger, and
        its slots are all used."""
        if batched:
            n = records_per_chunk(self.save_every)
            return n, n
        return SINGLE_RECORDS, max(1, min(SINGLE_RECORDS, -(-CHUNK_STEPS // self.save_every)))

    def chunks(self, batched: bool) -> int:
        """Number of compiled chunks the run takes."""
        return -(-self.samples // self.chunk(batched)[1])


def records_per_chunk(save_every: int) -> int:
    """Stored samples per compiled chunk of a BATCH for a sample every ``save_every`` steps: 2000
    for every step, 200 for 2–10 steps between samples (400–2,000 steps per chunk), 20 beyond
    (220 steps or more: 20,000 for one sample per 1,000 steps, a few seconds of computing between
    progress reports). ``save_every`` is a traced argument of the chunk program, so every output
    interval and dt with the same count shares one program."""
    if save_every <= 1:
        return CHUNK_STEPS
    return CHUNK_STEPS // 10 if save_every <= 10 else CHUNK_STEPS // 100


def save_every_for(n_steps: int, dt: float, save_interval: float) -> int:
    """The largest divisor s of ``n_steps`` with s·dt ≤ ``save_interval`` (at least 1): samples
    stay uniform and the last one falls on t_final."""
    if not (is_real(save_interval) and math.isfinite(save_interval) and save_interval > 0):
        raise ConfigError(f"must be a finite number > 0, got {save_interval!r}", key="simulation.output_interval")
    limit = max(1, min(n_steps, int(math.floor(save_interval / dt * (1 + 1e-9)))))
    return max(s for s in range(1, limit + 1) if n_steps % s == 0)


__all__ = ["StepPlan", "DEFAULT_SAVE_INTERVAL", "CHUNK_STEPS", "SINGLE_RECORDS", "records_per_chunk",
           "save_every_for"]
