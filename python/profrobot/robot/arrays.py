"""A compiled MuJoCo model (``mjModel``) as the flat arrays the Rust core
(``profrobot._core.RobotModel``) labels with, and the fingerprint of what decides labels.

The arrays are copied from MuJoCo's *compiled* model, never re-parsed from XML, so bodies, hulls
and filters are MuJoCo's own; geom frames are taken the way ``mj_kinematics`` takes them
(:func:`geom_local_frames`). Base layer: numpy, mujoco and profrobot's errors.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np

from ..errors import InputError

FREE, BALL, SLIDE, HINGE = (int(t) for t in (mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_BALL,
                                            mujoco.mjtJoint.mjJNT_SLIDE, mujoco.mjtJoint.mjJNT_HINGE))
#: MuJoCo geom type → its name ("box", "mesh", ...), for the primitive and mesh types
GEOM_NAMES = {int(getattr(mujoco.mjtGeom, n)): n.removeprefix("mjGEOM_").lower() for n in dir(mujoco.mjtGeom) if n.startswith("mjGEOM_") and int(getattr(mujoco.mjtGeom, n)) < 9}


def object_name(m: mujoco.MjModel, obj: mujoco.mjtObj, i: int, prefix: str) -> str:
    """Object ``i``'s name in ``m``, or ``prefix`` + its index where it has none."""
    return mujoco.mj_id2name(m, obj, i) or f"{prefix}{i}"


def _frame(pos: np.ndarray, quat: np.ndarray, sameframe: int, inertial: tuple[np.ndarray, np.ndarray]
           ) -> tuple[np.ndarray, np.ndarray]:
    """A frame's pose in its body, taken the way ``mj_local2Global`` takes it.

    MuJoCo's compiler flags frames that (nearly) coincide with their body's frame or inertial
    frame (``*_sameframe``) and ``mj_kinematics`` then *copies* that frame instead of composing
    ``body · (pos, quat)``:
    0 none: (pos, quat); 1 body: (0, 1); 2 inertia: the inertial frame; 3 body rotation:
    (pos, 1); 4 inertial rotation: (pos, inertial quat).
    Composing the flagged pose instead leaves the geometry off MuJoCo's by up to the
    compiler's tolerance (seen: 3e-8 m on a gripper), enough to flip contacts on the boundary.
    With the frame returned here, ``body · frame`` equals MuJoCo's copy to rounding (1e-16 m).
    """
    one = np.array([1.0, 0.0, 0.0, 0.0])
    ipos, iquat = inertial
    sf = int(sameframe)
    if sf == 0:
        return pos, quat
    if sf == 1:
        return np.zeros(3), one
    if sf == 2:
        return ipos, iquat
    if sf == 3:
        return pos, one
    if sf == 4:
        return pos, iquat
    raise InputError(f"unknown MuJoCo sameframe flag {sf}")


def geom_local_frames(m: mujoco.MjModel, gids) -> tuple[np.ndarray, np.ndarray]:
    """(G, 3) positions and (G, 4) quaternions (w, x, y, z) of geoms ``gids`` in their bodies'
    frames, following MuJoCo's ``geom_sameframe`` flags (see :func:`_frame`)."""
    pos, quat = [], []
    for g in np.asarray(gids, dtype=int):
        b = int(m.geom_bodyid[g])
        ipos, iquat = m.body_ipos[b], m.body_iquat[b]
        inertial = _frame(ipos, iquat, m.body_sameframe[b], (ipos, iquat))   # flags 0, 1, 3: the frame is its own inertial
        p, q = _frame(m.geom_pos[g], m.geom_quat[g], m.geom_sameframe[g], inertial)
        pos.append(p)
        quat.append(q)
    return np.asarray(pos, dtype=np.float64).reshape(-1, 3), np.asarray(quat, dtype=np.float64).reshape(-1, 4)


def hull_vertices(m: mujoco.MjModel, mesh: int) -> np.ndarray:
    """The vertices MuJoCo collides for a mesh: its convex hull's when compiled, else all."""
    adr, num = m.mesh_vertadr[mesh], m.mesh_vertnum[mesh]
    verts = m.mesh_vert[adr:adr + num]
    gadr = m.mesh_graphadr[mesh]
    if gadr >= 0:
        # mesh_graph layout: numvert, numface, vert_edgeadr[numvert], vert_globalid[numvert], ...
        nv = int(m.mesh_graph[gadr])
        ids = m.mesh_graph[gadr + 2 + nv: gadr + 2 + 2 * nv]
        verts = verts[ids]
    return np.ascontiguousarray(verts, dtype=np.float64)


def model_arrays(m: mujoco.MjModel) -> dict[str, Any]:
    """The flat arrays (ModelDesc) the Rust core labels with, from a compiled model (numpy arrays,
    and the ``filter_parent`` and ``contact_enabled`` flags as bools)."""
    f64 = lambda a, cols=None: np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape(-1, cols) if cols
                                                    else np.asarray(a, dtype=np.float64))
    i32 = lambda a: np.ascontiguousarray(a, dtype=np.int32)
    collidable = (m.geom_contype != 0) | (m.geom_conaffinity != 0)
    collidable[m.pair_geom1] = True
    collidable[m.pair_geom2] = True
    gids = np.flatnonzero(collidable)
    override = bool(m.opt.enableflags & mujoco.mjtEnableBit.mjENBL_OVERRIDE)
    geom_margin = m.geom_margin[gids].copy()
    pair_margin = m.pair_margin.copy()
    if override:  # mj_assignMargin: every contact uses o_margin
        geom_margin[:] = m.opt.o_margin / 2
        pair_margin[:] = m.opt.o_margin

    mesh_ids = sorted({int(m.geom_dataid[g]) for g in gids if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH})
    mesh_index = {mid: i for i, mid in enumerate(mesh_ids)}
    hulls = [hull_vertices(m, mid) for mid in mesh_ids]
    adr = np.cumsum([0] + [len(h) for h in hulls])[:-1]
    geom_mesh = [mesh_index.get(int(m.geom_dataid[g]), -1) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH else -1
                 for g in gids]
    geom_pos, geom_quat = geom_local_frames(m, gids)
    excl = np.array([[s >> 16, s & 0xFFFF] for s in m.exclude_signature], dtype=np.int32).reshape(-1, 2)
    dis = m.opt.disableflags
    return dict(
        body_parent=i32(m.body_parentid), body_weld=i32(m.body_weldid),
        body_pos=f64(m.body_pos, 3), body_quat=f64(m.body_quat, 4),
        jnt_type=i32(m.jnt_type), jnt_body=i32(m.jnt_bodyid), jnt_pos=f64(m.jnt_pos, 3),
        jnt_axis=f64(m.jnt_axis, 3), jnt_qpos0=f64(m.qpos0[m.jnt_qposadr]),
        jnt_range=f64(m.jnt_range, 2), jnt_limited=np.ascontiguousarray(m.jnt_limited != 0),
        geom_id=i32(gids), geom_type=i32(m.geom_type[gids]), geom_body=i32(m.geom_bodyid[gids]),
        geom_pos=f64(geom_pos, 3), geom_quat=f64(geom_quat, 4),
        geom_size=f64(m.geom_size[gids], 3),
        geom_contype=np.ascontiguousarray(m.geom_contype[gids], dtype=np.uint32),
        geom_conaffinity=np.ascontiguousarray(m.geom_conaffinity[gids], dtype=np.uint32),
        geom_margin=f64(geom_margin), geom_mesh=i32(geom_mesh),
        mesh_vert_adr=np.ascontiguousarray(adr, dtype=np.uint32),
        mesh_vert_num=np.ascontiguousarray([len(h) for h in hulls], dtype=np.uint32),
        mesh_vert=f64(np.concatenate(hulls) if hulls else np.zeros((0, 3)), 3),
        exclude=excl,
        pair_geom=np.ascontiguousarray(np.stack([m.pair_geom1, m.pair_geom2], axis=1), dtype=np.int32).reshape(-1, 2),
        pair_margin=f64(pair_margin),
        filter_parent=not (dis & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT),
        contact_enabled=not (dis & (mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)),
    )


def label_fingerprint(joint_names: list[str], arrays: dict[str, np.ndarray], scene_joints: Sequence[str] = ()) -> str:
    """sha256 of everything that decides labels: joints, bodies, geoms, hulls, filters (and, for a
    family of scenes, which joints are scene joints)."""
    h = hashlib.sha256()
    h.update("\0".join(joint_names).encode())
    if scene_joints:
        h.update(("scene:" + "\0".join(scene_joints)).encode())
    for key in sorted(arrays):
        if key == "jnt_scene" or key.startswith("eq_"):  # scene joints: by name above; couplings decide no label
            continue
        v = np.asarray(arrays[key])
        h.update(key.encode())
        h.update(np.ascontiguousarray(np.round(v, 12) if v.dtype.kind == "f" else v).tobytes())
    return h.hexdigest()[:32]
