"""The registries that map a scenario's strings to classes.

====================  ===========  =====================================================
scenario key          registry     values shipped
====================  ===========  =====================================================
``*.arm.model``       ``ARMS``     ``two_link``, ``planar``, ``urdf``
``*.surface.kind``    ``SURFACES`` ``inclined_line``; ``plane``, ``sphere``, ``cylinder`` (3-D);
                                   ``circle``, ``line``, ``sine`` (2-D); ``python``
``plant.engine``      ``PLANTS``   ``hinfnn`` (default)
``task.map``          ``TASKS``    ``native`` (default), ``planar``, ``pose``, ``fitted``
``reference.kind``    ``REFERENCES`` ``cosine`` (default), ``cosines``
``controller.kind``   ``hinfnn.controllers.KINDS``: ``fl``, ``hinf``, ``hinf_nn``
====================  ===========  =====================================================

A new kind is a section dataclass with a ``build()`` method (see :mod:`hinfnn.scenario.sections`)
registered with one line, e.g.::

    @SURFACES.register("circle")
    @section
    class CircleConfig(SurfaceConfig):
        radius: float = param(doc="radius, m", gt=0)
        def build(self): return Circle(radius=self.radius, ...)

and a new controller kind is ``hinfnn.controllers.register(Composition(...))``.
"""

from __future__ import annotations

from .schema import Registry

ARMS = Registry("arm model", "model")
SURFACES = Registry("surface kind", "kind")
PLANTS = Registry("physics engine of the true plant", "engine", default="hinfnn")
TASKS = Registry("task coordinates", "map", default="native")
REFERENCES = Registry("reference kind", "kind", default="cosine")

__all__ = ["ARMS", "SURFACES", "PLANTS", "TASKS", "REFERENCES", "Registry"]
