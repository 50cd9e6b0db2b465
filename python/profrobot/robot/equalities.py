"""Coupled joints: MuJoCo equality constraints and tendons, and poses that respect them.

A model's equalities tie joints together. Sampling every joint independently breaks them: a
gripper whose second finger mirrors the first through a joint equality, or whose linkage is
closed by ``connect`` equalities, then takes poses it can never reach (and often self-collides
in them). Three treatments, chosen with ``equalities=`` in :func:`profrobot.sample_poses` and
:func:`profrobot.make_dataset`:

- ``"auto"`` (default): joint equalities (MuJoCo ``<equality><joint>``, polynomial couplings)
  are enforced exactly: the independent joints are sampled, every dependent joint is computed
  from MuJoCo's polynomial (to rounding, far below 1e-9). Closed-loop (connect/weld) and tendon
  equalities are left free, and the robot warned about them when it was built.
- ``"settle"``: as ``"auto"``, then every active equality (connect, weld, joint, tendon) is
  satisfied by projecting each pose onto the constraint manifold with MuJoCo's own constraint
  rows (Gauss-Newton on ``efc_pos`` with the minimum-norm step ``-J⁺ r``, contacts and limits
  disabled). Poses that do not settle within the tolerance, or that end outside a joint's
  limits, are replaced by further seeded draws.
- ``"ignore"``: every joint uniform and independent (the behaviour before couplings existed).

What a field learns follows the poses it is trained on: with ``"auto"``/``"settle"`` it learns
the collision boundary on the constraint manifold (the poses a real robot can take) and says
nothing reliable off it; with ``"ignore"`` it learns the boundary in the full joint box.

MuJoCo's joint equality (``engine_core_constraint.c``): with y the position of ``joint1``, x
of ``joint2``, and y0, x0 their ``qpos0``,
``y - y0 = a0 + a1 d + a2 d² + a3 d³ + a4 d⁴`` where ``d = x - x0``; without ``joint2``,
``y = y0 + a0``.
"""

from __future__ import annotations

import copy
import functools
from dataclasses import dataclass
from typing import Literal

import mujoco
import numpy as np
from ..errors import InputError

EqualityMode = Literal["auto", "settle", "ignore"]
EQUALITY_MODES = ("auto", "settle", "ignore")

_KINDS = {int(mujoco.mjtEq.mjEQ_CONNECT): "connect", int(mujoco.mjtEq.mjEQ_WELD): "weld",
          int(mujoco.mjtEq.mjEQ_JOINT): "joint", int(mujoco.mjtEq.mjEQ_TENDON): "tendon"}
_OBJ = {"connect": mujoco.mjtObj.mjOBJ_BODY, "weld": mujoco.mjtObj.mjOBJ_BODY,
        "joint": mujoco.mjtObj.mjOBJ_JOINT, "tendon": mujoco.mjtObj.mjOBJ_TENDON}


class EqualityWarning(UserWarning):
    """A model has couplings that uniform sampling does not enforce by default."""


@dataclass(frozen=True)
class Equality:
    """One MuJoCo equality constraint.

    Attributes:
        kind: ``"joint"``, ``"tendon"``, ``"connect"``, ``"weld"`` (or MuJoCo's type number as
            a string for others, e.g. flex).
        name: its MJCF name, or ``equality<i>``.
        obj1, obj2: names of the constrained objects (joints, tendons or bodies; ``None`` when
            MuJoCo has none, e.g. a joint fixed to a constant).
        polycoef: (5,) a0..a4 of a joint/tendon coupling (zeros otherwise).
        active: MuJoCo's ``eq_active0``.
        closed_loop: connect/weld: a kinematic loop the tree FK cannot express.
    """

    kind: str
    name: str
    obj1: str | None
    obj2: str | None
    polycoef: tuple[float, ...]
    active: bool

    @property
    def closed_loop(self) -> bool:
        return self.kind in ("connect", "weld")

    @property
    def enforced_by_default(self) -> bool:
        """Whether ``equalities="auto"`` sampling satisfies it (joint couplings only)."""
        return self.kind == "joint" and self.active


@dataclass(frozen=True)
class Tendon:
    """A fixed tendon (a linear combination of joints, ``length = Σ coef_j q_j``) or a spatial
    one; tendons change no collision geometry, they matter only through equalities and limits."""

    name: str
    fixed: bool
    joints: tuple[str, ...]
    coef: tuple[float, ...]
    limited: bool
    range: tuple[float, float]


def _name(m: mujoco.MjModel, obj, i: int, prefix: str) -> str | None:
    if i < 0:
        return None
    return _id_name(m, obj, i, prefix)


def _id_name(m: mujoco.MjModel, obj, i: int, prefix: str) -> str:
    """The name of object ``i`` (>= 0), or ``prefix`` and its index when it has none."""
    return mujoco.mj_id2name(m, obj, i) or f"{prefix}{i}"


def read_equalities(m: mujoco.MjModel) -> list[Equality]:
    out = []
    for i in range(m.neq):
        kind = _KINDS.get(int(m.eq_type[i]), str(int(m.eq_type[i])))
        obj = _OBJ.get(kind)
        n1 = _name(m, obj, int(m.eq_obj1id[i]), kind) if obj is not None else str(int(m.eq_obj1id[i]))
        n2 = _name(m, obj, int(m.eq_obj2id[i]), kind) if obj is not None else str(int(m.eq_obj2id[i]))
        poly = tuple(float(c) for c in m.eq_data[i, :5]) if kind in ("joint", "tendon") else (0.0,) * 5
        out.append(Equality(kind, _id_name(m, mujoco.mjtObj.mjOBJ_EQUALITY, i, "equality"), n1, n2, poly,
                            bool(m.eq_active0[i])))
    return out


def read_tendons(m: mujoco.MjModel) -> list[Tendon]:
    out = []
    for t in range(m.ntendon):
        adr, num = int(m.tendon_adr[t]), int(m.tendon_num[t])
        types = m.wrap_type[adr:adr + num]
        fixed = bool(np.all(types == mujoco.mjtWrap.mjWRAP_JOINT))
        joints = tuple(_id_name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.wrap_objid[w]), "joint")   # a joint wrap names its joint
                       for w in range(adr, adr + num) if m.wrap_type[w] == mujoco.mjtWrap.mjWRAP_JOINT)
        coef = tuple(float(m.wrap_prm[w]) for w in range(adr, adr + num) if m.wrap_type[w] == mujoco.mjtWrap.mjWRAP_JOINT)
        out.append(Tendon(_id_name(m, mujoco.mjtObj.mjOBJ_TENDON, t, "tendon"), fixed, joints, coef,
                          bool(m.tendon_limited[t]), (float(m.tendon_range[t, 0]), float(m.tendon_range[t, 1]))))
    return out


def unenforced_summary(equalities: list[Equality], tendons: list[Tendon]) -> str | None:
    """One line naming what ``equalities="auto"`` sampling leaves free, or None."""
    loose = [e for e in equalities if e.active and not e.enforced_by_default]
    limited = [t for t in tendons if t.limited]
    if not loose and not limited:
        return None
    parts = []
    if loose:
        parts.append(", ".join(f"{e.kind} equality {e.name!r} ({e.obj1}, {e.obj2})" for e in loose))
    if limited:
        parts.append(", ".join(f"limited tendon {t.name!r}" for t in limited))
    return "; ".join(parts)


class JointCouplings:
    """Joint equalities compiled for sampling: dependent joints computed from independent ones.

    Dependent joints are evaluated in dependency order (a chain a = f(b), b = g(c) works);
    a joint constrained twice, or a cycle, is refused with the equalities named.
    """

    def __init__(self, m: mujoco.MjModel, joint_names: list[str]):
        rows = []  # (dependent, independent or -1, coefficients, y0, x0, equality name)
        for i, e in enumerate(read_equalities(m)):
            if e.kind != "joint" or not e.active:
                continue
            j1, j2 = int(m.eq_obj1id[i]), int(m.eq_obj2id[i])
            y0 = float(m.qpos0[m.jnt_qposadr[j1]])
            x0 = float(m.qpos0[m.jnt_qposadr[j2]]) if j2 >= 0 else 0.0
            rows.append((j1, j2, np.asarray(e.polycoef), y0, x0, e.name))
        deps: dict[int, tuple] = {}
        for r in rows:
            if r[0] in deps:
                raise InputError(f"joint {joint_names[r[0]]!r} is the dependent joint of two joint equalities "
                                 f"({deps[r[0]][5]!r} and {r[5]!r}); sampling cannot satisfy both")
            deps[r[0]] = r
        order: list[tuple] = []
        state: dict[int, str] = {}

        def visit(j, path):
            if state.get(j) == "done" or j not in deps:
                return
            if state.get(j) == "busy":
                names = " -> ".join(joint_names[k] for k in path + [j])
                raise InputError(f"joint equalities form a cycle ({names}); sampling needs an independent joint")
            state[j] = "busy"
            if deps[j][1] >= 0:
                visit(deps[j][1], path + [j])
            state[j] = "done"
            order.append(deps[j])

        for j in sorted(deps):
            visit(j, [])
        self.rows = order

    def __bool__(self) -> bool:
        return bool(self.rows)

    @property
    def dependent(self) -> list[int]:
        return [r[0] for r in self.rows]

    def apply(self, poses: np.ndarray) -> np.ndarray:
        """Overwrite the dependent columns of ``poses`` (B, K) in place; returns it."""
        for j1, j2, a, y0, x0, _ in self.rows:
            if j2 < 0:
                poses[:, j1] = y0 + a[0]
            else:
                d = poses[:, j2] - x0
                poses[:, j1] = y0 + a[0] + d * (a[1] + d * (a[2] + d * (a[3] + d * a[4])))
        return poses

    @functools.cached_property
    def linear(self) -> bool:
        """Whether every coupling is affine (a straight motion between coupled poses stays on it);
        read once (``time_path`` asks on every call)."""
        return all(not np.any(a[2:]) for _, _, a, _, _, _ in self.rows)

    def arrays(self) -> dict[str, np.ndarray]:
        """The couplings for the Rust core (``rust/joints/couplings.rs``): ``eq_dep`` (E,) uint32,
        ``eq_indep`` (E,) int32 (-1: locked), ``eq_coef`` (E, 5), ``eq_origin`` (E, 2) float64."""
        rows = self.rows
        return dict(eq_dep=np.array([r[0] for r in rows], dtype=np.uint32),
                    eq_indep=np.array([r[1] for r in rows], dtype=np.int32),
                    eq_coef=np.array([r[2] for r in rows], dtype=np.float64).reshape(-1, 5),
                    eq_origin=np.array([(r[3], r[4]) for r in rows], dtype=np.float64).reshape(-1, 2))

    def residual(self, poses: np.ndarray) -> np.ndarray:
        """(B,) max |violation| over the joint equalities, in radians / metres."""
        out = np.zeros(len(poses))
        for j1, j2, a, y0, x0, _ in self.rows:
            d = poses[:, j2] - x0 if j2 >= 0 else 0.0
            want = y0 + a[0] + d * (a[1] + d * (a[2] + d * (a[3] + d * a[4])))
            out = np.maximum(out, np.abs(poses[:, j1] - want))
        return out


def _settle_model(m: mujoco.MjModel) -> mujoco.MjModel:
    """A copy that builds only equality rows, with a dense Jacobian."""
    mc = copy.deepcopy(m)
    mc.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_LIMIT
                               | mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS)
    mc.opt.jacobian = int(mujoco.mjtJacobian.mjJAC_DENSE)
    return mc


def _equality_rows(mc: mujoco.MjModel, d: mujoco.MjData, q: np.ndarray, qpos_adr: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's active equality rows at pose ``q``: residuals ``efc_pos`` (R,) and the dense
    Jacobian ``efc_J`` (R, nv) (``mc`` from :func:`_settle_model`)."""
    d.qpos[qpos_adr] = q
    mujoco.mj_fwdPosition(mc, d)
    eq = d.efc_type[:d.nefc] == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    return d.efc_pos[:d.nefc][eq], d.efc_J[:d.nefc * mc.nv].reshape(d.nefc, mc.nv)[eq]


def equality_residual(m: mujoco.MjModel, poses: np.ndarray, qpos_adr: np.ndarray) -> np.ndarray:
    """(B,) max |efc_pos| over MuJoCo's active equality rows at each pose (metres / radians)."""
    mc = _settle_model(m)
    d = mujoco.MjData(mc)
    out = np.zeros(len(poses))
    for b, q in enumerate(poses):
        r, _ = _equality_rows(mc, d, q, qpos_adr)
        out[b] = np.abs(r).max() if r.size else 0.0
    return out


def settle(m: mujoco.MjModel, poses: np.ndarray, qpos_adr: np.ndarray, dof_adr: np.ndarray, *,
           tol: float = 1e-10, iterations: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """Project each pose onto the manifold of MuJoCo's active equalities.

    Gauss-Newton with the minimum-norm step: ``q ← q − J⁺ r`` where r = ``efc_pos`` and J =
    ``efc_J`` of the equality rows (``mj_fwdPosition`` with contacts, limits and friction loss
    disabled). Returns (poses (B, K), ok (B,)): ok where max |r| ≤ ``tol`` was reached.
    """
    mc = _settle_model(m)
    d = mujoco.MjData(mc)
    out = np.array(poses, dtype=np.float64, copy=True)
    ok = np.zeros(len(out), dtype=bool)
    for b in range(len(out)):
        q = out[b]
        for _ in range(iterations):
            r, J = _equality_rows(mc, d, q, qpos_adr)
            if r.size == 0 or np.abs(r).max() <= tol:
                ok[b] = np.isfinite(q).all()
                break
            step, *_ = np.linalg.lstsq(J[:, dof_adr], r, rcond=None)
            q = q - step
            if not np.isfinite(q).all():
                break
        out[b] = q
    return out, ok
