"""How the compiled simulation loop is written for XLA's CPU runtime: the loop options, a value.

Each option changes how XLA executes the loop, never what it computes (the numbers agree to
rounding, most of them bit for bit). docs/performance.md ("The loop's devices") names the benchmark
line that shows what each one buys; ``python benchmarks/run.py --cases device_run --disable NAME``
(the paper's arm) or ``--cases arm_run --disable NAME`` (the UR5) turns one off, in a fresh process.

:class:`LoopOptions` is passed to :func:`hinfnn.simulate` (``loop=``) and is part of the key of
the compiled program: a program traced with some options is never reused with others. The
simulator makes them for its plant once per program (:meth:`LoopOptions.for_joints`) and hands
them on as values: the options of the step and the record (``rolled_rk4``, ``rolled_stages``,
``record_once``, ``record_blocks``, ``frozen_law``) to the functions that write the loop, and
those of the small linear algebra (``sincos``, ``small_mm``, ``arm_kernels``, ``member_minor``) as
a :class:`hinfnn._linalg.Kernels` value (:meth:`~hinfnn._linalg.Kernels.loop`) that the plant,
the controller and the reference hold while the program is traced
(:meth:`~hinfnn._linalg.Kernels.hold`). Nothing reads them from a context.

``sincos``
    Sines and cosines of a vector of angles computed once and shared: XLA counts them as cheap and
    recomputes them inside every kernel that uses them; a reduction is never recomputed, so the
    values pass through a sum with 0·v (exact for finite values; NaN stays NaN).
``small_mm``
    Products of small matrices (contractions of at most :data:`hinfnn._linalg.SMALL_MM` terms)
    written as multiply-and-sum, which XLA fuses with the neighbouring arithmetic; a ``dot`` is a
    kernel of its own.
``rolled_rk4``
    RK4's four stages as a loop of four iterations, so the compiled step holds the plant and the
    controller once instead of four times (the same operations in the same order, bit for bit).
    ``None`` (default): for arms of at least :data:`ROLL_FROM_JOINTS` joints, where it saves
    compile time; the paper's 2-joint arm keeps the stages written out (rolled, it runs slower).
``arm_kernels``
    For arms of at least :data:`ROLL_FROM_JOINTS` joints (``None``, the default; ``True``/``False``
    force it): products of small matrices with contractions of 3 to
    :data:`hinfnn._linalg.SMALL_MM` terms written as a sum of products term by term (no reduction:
    a reduction is a kernel of its own in XLA's CPU compiler, the elementwise sum fuses with its
    neighbours), the written-out Cholesky factorisation and solves of :mod:`hinfnn._linalg`
    with their columns computed once and kept (:meth:`hinfnn._linalg.Kernels.store`), and the products that
    several kernels read computed once (:meth:`hinfnn._linalg.Kernels.stored`: the nominal reduced-order
    model's Ĵ⁻¹, B̄, M̂Ĵ⁻¹, Ĵ⁻¹S, the task map's relative rotation), so fewer kernels run per step.
    The paper's 2-joint arm keeps its reductions (its numbers bit for bit).
``rolled_stages``
    With RK4 rolled: 4 (default), all four stages a loop (the record computed at the first stage,
    ``record_once``); 3, stage 1 (the one that gives the record) written out and stages 2–4 a
    loop (the record computed once per step, but the plant and the controller twice in the
    program). XLA's CPU runtime pays for each kernel it launches more the more distinct kernels a
    loop holds (``benchmarks/run.py --cases launch_floor``), so the program with fewer distinct
    kernels runs faster although it launches more, and it compiles in less time.
``record_once``
    With RK4's four stages one loop: the step's function cut in two
    (:func:`hinfnn.sim.integrate.split_aux`), the operations only the record needs (the plant's
    and the controller's recorded signals, the fault measures) under a ``lax.cond`` taken at the
    first stage, the rest at every stage. The program still holds the plant and the controller
    once; the record is computed once per step instead of four times. The numbers agree to
    rounding, not bit for bit, since XLA fuses the operations otherwise. At the steps that store
    no sample only the record's entries every step reads are computed
    (:data:`hinfnn.sim.simulate.EVERY_STEP`, the ``take`` of
    :meth:`hinfnn.sim.integrate.RK4.step`). False: the record computed at every stage and the
    first kept.
``fusion_emitters``
    For arms of at least :data:`ROLL_FROM_JOINTS` joints (``None``, the default), the simulation's
    programs are compiled with XLA's older CPU loop emitters (the compile option
    ``xla_cpu_use_fusion_emitters=False`` of those programs alone, :meth:`LoopOptions.compiler_options`):
    the arm's rigid-body algorithms written out for fusion (:mod:`hinfnn.model.rbd`) make large
    fused kernels, which XLA's default emitters compile several times slower. ``True``: XLA's
    defaults for every arm. The paper's 2-joint arm keeps XLA's defaults.
``record_blocks``
    The stored samples of a chunk taken by a scan over blocks of samples, each block an inner
    scan of as many samples as keep every array the inner loop stacks within
    :data:`SEQUENTIAL_VALUES` values. XLA's CPU runtime runs a loop body's kernels one after the
    other only when no kernel touches a larger buffer; the body that writes one sample into the
    chunk's stacked records (200 × 6 values for a UR5's τ) otherwise sends its kernels (the sample
    update of sampled control, σ_min's SVD, the record's copies) through its dataflow scheduler and
    its thread pool, once per sample. False: one scan over the samples.
``batch_group``
    A batch of more than this many members runs as equal groups of at most that many, one after
    the other, through one compiled program (the last group padded with copies of its first
    member, whose results are dropped); 0: one group. ``None`` (the default): chosen by the arm,
    :data:`BATCH_GROUP_PLANAR` members for 2 joints, :data:`BATCH_GROUP_ARM` from
    :data:`ROLL_FROM_JOINTS` joints. The two-link arm's step is a few hundred kernels of little
    arithmetic, and past about a hundred members its vmapped arrays leave the cache; a 6-DOF arm's
    thousand kernel launches per step cost the same for any number of members, so larger groups
    amortise them.
``member_minor``
    In a batch (``jax.vmap``) of at least :data:`MEMBER_MINOR_FROM` members of an arm of at least
    :data:`ROLL_FROM_JOINTS` joints (``None``, the default): every stored value
    (:meth:`hinfnn._linalg.Kernels.store`, :meth:`~hinfnn._linalg.Kernels.stored`,
    :func:`hinfnn.model.rbd.keep`) laid out in memory with the member axis minor
    (:meth:`hinfnn._linalg.Kernels.member_minor`), the programs' outputs in the default layout
    (:meth:`hinfnn._linalg.Kernels.default_layout`). ``vmap`` puts the member axis first: a member's
    6 × 6 matrix is then 36 adjacent values and a kernel that reads it vectorises over a row of 6;
    member-minor, each entry is a vector over the members. It costs compile time (XLA converts
    layouts in many fused copies), which a batch of a few runs (an experiment's pair of laws)
    would not earn back. No effect on a single run (no member axis) or on the two-link arm
    (nothing stored).
``frozen_law``
    Under sampled control (a zero-order hold, ``control_period``) the law's state is frozen between
    samples, its rate zero: RK4's four stages integrate the plant and the theorems' accumulators
    alone and the law's state passes through, instead of RK4 adding dt/6 · 0 to every weight of the
    networks at every stage (the same numbers bit for bit, fewer kernels per step). No effect under
    continuous control.

The controller's own layout (the networks' weights carried in blocks of at most 64 values, so that
XLA runs the loop's kernels inline) is the controller's business
(:class:`hinfnn.controllers.law.ReducedOrderController`, ``block``), not a loop option.
"""

from __future__ import annotations

import dataclasses

#: Arms with at least this many joints integrate with RK4's stages rolled (``rolled_rk4=None``).
ROLL_FROM_JOINTS = 3
#: XLA's CPU runtime runs a loop body's kernels one after the other, in the calling thread, only
#: when no buffer they touch holds more than this many float64 values (512 bytes,
#: ``execute_sequential_buffer_threshold`` in XLA's CPU executable); else through its dataflow
#: scheduler and thread pool.
SEQUENTIAL_VALUES = 64
#: ``batch_group`` by the arm (``None``): the two-link arm's groups, and those of larger arms.
BATCH_GROUP_PLANAR = 100
BATCH_GROUP_ARM = 4096
#: ``member_minor`` by the batch (``None``): on for batches of at least this many members of an arm.
MEMBER_MINOR_FROM = 16


@dataclasses.dataclass(frozen=True)
class LoopOptions:
    """How the compiled loop is written (see the module docstring); hashable, part of the key of
    every compiled simulation program."""

    sincos: bool = True
    small_mm: bool = True
    rolled_rk4: bool | None = None
    batch_group: int | None = None
    arm_kernels: bool | None = None
    rolled_stages: int = 4
    fusion_emitters: bool | None = None
    record_once: bool = True
    record_blocks: bool = True
    member_minor: bool | None = None
    frozen_law: bool = True

    def __post_init__(self):
        if self.batch_group is not None and not (isinstance(self.batch_group, int) and self.batch_group >= 0):
            raise ValueError(f"batch_group must be a whole number >= 0 (0: off) or None (by the arm), "
                             f"got {self.batch_group!r}")
        if self.rolled_stages not in (3, 4):
            raise ValueError(f"rolled_stages must be 3 or 4, got {self.rolled_stages!r}")

    def rolled(self, n_joints: int) -> bool:
        """Whether a plant with ``n_joints`` joints integrates with RK4's stages rolled."""
        return n_joints >= ROLL_FROM_JOINTS if self.rolled_rk4 is None else bool(self.rolled_rk4)

    def for_joints(self, n_joints: int, members: int | None = None) -> "LoopOptions":
        """These options with the choices left to the arm (``None``) made for ``n_joints`` joints:
        what the simulator traces a plant of that size with. ``member_minor`` is the batch's choice:
        made for a batch of ``members`` members, left ``None`` (off) without."""
        big = n_joints >= ROLL_FROM_JOINTS
        group = (BATCH_GROUP_ARM if big else BATCH_GROUP_PLANAR) if self.batch_group is None else self.batch_group
        minor = self.member_minor
        if minor is None and members is not None:
            minor = big and members >= MEMBER_MINOR_FROM
        return dataclasses.replace(self, rolled_rk4=self.rolled(n_joints), batch_group=group,
                                   arm_kernels=big if self.arm_kernels is None else bool(self.arm_kernels),
                                   fusion_emitters=(not big) if self.fusion_emitters is None
                                   else bool(self.fusion_emitters),
                                   member_minor=minor if minor is None else bool(minor))

    def compiler_options(self, n_joints: int) -> dict | None:
        """XLA compile options of a simulation program for a plant of ``n_joints`` joints
        (``fusion_emitters``): None for XLA's defaults."""
        return None if self.for_joints(n_joints).fusion_emitters else {"xla_cpu_use_fusion_emitters": False}

    def groups(self, B: int, n_joints: int = 2) -> list:
        """Member indices of the groups a batch of B members of an arm of ``n_joints`` joints runs
        in: one group of all when B ≤ ``batch_group`` (:meth:`for_joints`) or grouping is off, else
        equal groups (NumPy index arrays, the last padded with its first member)."""
        import numpy as np

        group = self.for_joints(n_joints).batch_group
        if not group or B <= group:
            return [np.arange(B)]
        n = -(-B // group)
        g = -(-B // n)
        groups = []
        for i in range(n):
            idx = np.arange(i * g, min((i + 1) * g, B))
            groups.append(np.concatenate([idx, np.full(g - idx.size, idx[0])]))
        return groups


__all__ = ["BATCH_GROUP_ARM", "BATCH_GROUP_PLANAR", "LoopOptions", "MEMBER_MINOR_FROM", "ROLL_FROM_JOINTS",
           "SEQUENTIAL_VALUES"]
