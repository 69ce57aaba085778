"""The compiled entries of the programs that run once per process (setup and design) and of the
loop programs made outside the simulator, for their callers: the plain functions of ``model/``,
``controllers/`` and ``plant/`` (and the path check's own program) with hinfnn's compile decorators
applied here, so that the modules that define them import none of the compile machinery
(:mod:`hinfnn._programs`, :mod:`hinfnn._loop`, :mod:`hinfnn._cache`; docs/architecture.md,
"Writing code the loop runs", rule 8).

* :func:`compile_declared`: the programs those modules declare and call themselves
  (:mod:`hinfnn._declared`: the start pose's solve, the effective mass, ``check_start``'s det Ĵ,
  the force-rate design's poses and measures, the robust laws' sizing), each compiled at its first
  call.
* :func:`loop_jit`: the robot loop's update (:class:`hinfnn.controllers.SampledController`),
  compiled with the simulator's XLA options for the arm.

* :func:`approach_pose`: :func:`hinfnn.controllers.job.approach_pose` as a design-time program
  (:func:`hinfnn._programs.jit_by_joints`), for :attr:`hinfnn.scenario.Setup.start_q`.
* :func:`path_joints`: the nominal inverse kinematics along the reference's path
  (:func:`path_joints_plain`), kept traced and lowered on disk between processes
  (:func:`hinfnn._programs.kept`), for the scenario's joint-limit check
  (:mod:`hinfnn.scenario.checks`): a sweep checks every draw with it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._loop import LoopOptions
from ._programs import jit_by_joints, kept
from .controllers import job


def compile_declared(program):
    """The compiled form of a program declared below the callers (:class:`hinfnn._declared.DeclaredProgram`):
    a setup program as :func:`hinfnn._programs.kept` under its name, a design program as
    :func:`hinfnn._programs.jit_by_joints` with its static arguments; the same programs as the
    decorators applied where the function is defined."""
    if program.kind == "setup":
        return kept(program.name)(program.fn)
    return jit_by_joints(program.fn, static_argnames=program.static_argnames)


def loop_jit(fn, n_joints: int, **jit_kwargs):
    """``jax.jit(fn, **jit_kwargs)`` compiled with the simulator's XLA options for an arm of
    ``n_joints`` joints (:meth:`hinfnn._loop.LoopOptions.compiler_options`: XLA's older loop
    emitters on arms of 3 joints or more, XLA's defaults for the two-link arm)."""
    return jax.jit(fn, compiler_options=LoopOptions().compiler_options(n_joints), **jit_kwargs)


def path_joints_plain(arm, surf, ref, t, q0):
    """Joint angles along x_d(t) = (u1d(t), Ω(u1d(t))) of the reference ``ref`` at the times ``t``:
    the nominal arm's inverse kinematics, 8 Newton steps of at most 0.2 rad per sample, continued
    from the previous sample's pose (the first from ``q0``); ``(q (N, n), ‖ĥ(q) − x_d‖∞ (N,))``."""

    def one(q, ti):
        u1 = ref(ti).u1_d
        x = jnp.concatenate([u1, surf.Omega(u1)])

        def newton(_, q):
            step = jnp.linalg.solve(arm.J(q), arm.h(q) - x)
            return q - step * jnp.minimum(1.0, 0.2 / jnp.maximum(jnp.max(jnp.abs(step)), 1e-300))

        q = jax.lax.fori_loop(0, 8, newton, q)
        return q, (q, jnp.max(jnp.abs(arm.h(q) - x)))

    return jax.lax.scan(one, q0, t)[1]


#: :func:`path_joints_plain` compiled and kept (its first argument an arm: by its joints).
path_joints = kept("path_joints")(path_joints_plain)

#: :func:`hinfnn.controllers.job.approach_pose` compiled as a design-time program.
approach_pose = jit_by_joints(job.approach_pose)

__all__ = ["approach_pose", "compile_declared", "loop_jit", "path_joints", "path_joints_plain"]
