"""Run cases: what one run of an experiment is, as data.

A :class:`Case` is a name, a scenario with one controller kind, the overrides that made it from
the experiment's base scenario, and tags: what the run stands for in its experiment (``variant =
"stable"``, ``mode = "1kHz"``, ``stiffness = 1e5``, ``contact = "damped"``, the compared key and
value ...) and the facts a report shows of it (:func:`describe`: the controller's label, the
contact, the units of λ, the names of the task coordinates). Reports read tags; they never parse a
run's name and never read a scenario (:func:`hinfnn.scenario.describe`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from ..scenario.setup import KIND_COLORS, describe


@dataclasses.dataclass(frozen=True)
class Case:
    """One run of an experiment.

    ``scenario``: the scenario with this run's one controller kind; ``overrides``: what this case
    sets on top of the experiment's base scenario (recorded in ``metrics.json``); ``tags``: what
    the run stands for and what reports show of it; ``label``: how reports name it (default: the
    controller's label with its variant); ``setup``: the objects its run is built from (a
    :class:`~hinfnn.scenario.setup.Setup` of the scenario this case's was made from, shared by the
    cases of one scenario, :func:`cases`; None: the case's scenario's own)."""

    name: str
    scenario: Any
    tags: dict = dataclasses.field(default_factory=dict)
    overrides: dict = dataclasses.field(default_factory=dict)
    label: str = ""
    setup: Any = dataclasses.field(default=None, compare=False, repr=False)

    def __post_init__(self):
        if "/" in self.name or not self.name:
            raise ValueError(f"a case name must be non-empty and contain no '/', got {self.name!r}")
        if len(self.scenario.kinds) != 1:
            raise ValueError(f"case {self.name!r}: its scenario must have one controller kind, got {self.scenario.kinds}")

    @property
    def kind(self) -> str:
        return self.scenario.kinds[0]

    def info(self):
        """The :class:`~hinfnn.sim.RunInfo` its run carries (label, colour, tags, scenario)."""
        from ..sim import RunInfo

        facts = describe(self.scenario)
        label = self.label or facts["label"]
        tags = {**facts, **self.tags, "label": label}
        return RunInfo(name=self.name, kind=self.kind, label=label, color=tags.get("color", ""), tags=tags,
                       scenario=self.scenario)

    def run(self):
        """The :class:`~hinfnn.sim.Run` to simulate (the scenario's objects, built once: those of
        ``setup`` when given, shared with the other cases of its scenario)."""
        setup = self.setup if self.setup is not None else self.scenario.build()
        return setup.run(self.kind, self.name, info=self.info())


def cases(scenario, *, prefix: str = "", suffix: str = "", tags: dict | None = None,
          overrides: dict | None = None) -> list[Case]:
    """One case per controller kind of ``scenario`` (named ``prefix + kind + suffix``), all built from
    the scenario's one :class:`~hinfnn.scenario.setup.Setup` (its plant, nominal models, reference
    and start pose built once, the controllers by kind)."""
    setup = scenario.build()
    return [Case(name=f"{prefix}{kind}{suffix}", scenario=scenario.single(kind), tags=dict(tags or {}),
                 overrides=dict(overrides or {}), setup=setup) for kind in scenario.kinds]


__all__ = ["Case", "cases"]
