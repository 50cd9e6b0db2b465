"""The MuJoCo reference labeller, and the side-by-side check of ours against it.

MuJoCo decides: a pose collides when ``mj_kinematics`` + ``mj_collision`` leave ``ncon > 0``. A
robot with a point cloud is checked against its :func:`~profrobot.robot.pointcloud.reference_model`: the
same balls as MuJoCo sphere geoms, every one of them reported as the cloud's id (-1) in pairs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np
import numpy.typing as npt

from .labels import Labels, as_poses, label_poses
from ..robot.pointcloud import CLOUD_GEOM_ID, cloud_geom_ids, reference_model, robot_geom_ids
from ..executors.base import Executor
from ..robot.gate import CLEARANCE, Layout, robot_at
from ..robot.robot import Robot


@dataclass
class MujocoLabels:
    """MuJoCo's verdict on B poses: contact count (the paper's "collision points") and pairs."""

    ncon: np.ndarray            # (B,) int
    collides: np.ndarray        # (B,) bool
    pairs: list[set[tuple[int, int]]]  # per pose, colliding (geom1, geom2) MuJoCo ids, sorted


def mujoco_labels_chunk(robot: Robot, poses: np.ndarray, start: int,
                        stop: int) -> tuple[np.ndarray, list[set[tuple[int, int]]]]:
    """MuJoCo's contact count and colliding geom pairs for each of ``poses[start:stop]``: the
    chunk function of :func:`mujoco_labels` (pure: every pose is labelled on its own)."""
    q = poses[start:stop]
    m = reference_model(robot)
    ids = robot_geom_ids(robot)
    as_id = lambda g: int(ids[g])
    d = mujoco.MjData(m)
    ncon = np.zeros(len(q), dtype=np.int64)
    pairs = []
    adr = robot.qpos_adr
    for i in range(len(q)):
        d.qpos[adr] = q[i]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        ncon[i] = d.ncon
        g = d.contact.geom[: d.ncon]
        pairs.append({(min(as_id(a), as_id(b)), max(as_id(a), as_id(b))) for a, b in g})
    return ncon, pairs


def mujoco_labels(robot: Robot, poses: npt.ArrayLike, *, layout: Layout | None = None, margin: float = CLEARANCE,
                  progress: bool = True, executor: Executor | None = None, chunk: int = 2000) -> MujocoLabels:
    """Labels ``poses`` (B, K) one by one with MuJoCo (the reference, single-threaded), in
    chunks of ``chunk`` poses (:func:`mujoco_labels_chunk`).

    ``executor``: ``None`` (here) or an executor (:mod:`profrobot.executors`): a
    :class:`~profrobot.executors.LocalExecutor` with ``processes > 1`` or a
    :class:`~profrobot.executors.RayExecutor` labels the chunks in parallel (the same labels:
    every pose is labelled on its own). ``layout``, ``margin``: as everywhere
    (:mod:`profrobot.robot.gate`): a family's θ at its layout, MuJoCo's margins widened.
    """
    from ..executors import check_executor, chunk_bounds, chunk_sizes

    robot = robot_at(robot, layout=layout, margin=margin, family=True)
    q = as_poses(robot, poses)
    executor = check_executor(executor)
    bounds = chunk_bounds(len(q), chunk)
    ref = executor.put(q)  # once (Ray: through the object store); each chunk names its rows
    parts = executor.map(mujoco_labels_chunk, [(ref, a, b) for a, b in bounds], robot=robot,
                         sizes=chunk_sizes(bounds), desc="mujoco", unit="pose", progress=progress)
    ncon = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, dtype=np.int64)
    pairs = [s for p in parts for s in p[1]]
    return MujocoLabels(ncon=ncon, collides=ncon > 0, pairs=pairs)


def mujoco_pair_distance(robot: Robot, pose: np.ndarray, g1: int, g2: int, distmax: float = 0.05) -> float:
    """MuJoCo's own signed distance between two geoms at ``pose`` (``mj_geomDistance``); the point
    cloud (id -1): the least over its balls."""
    m = reference_model(robot)
    d = mujoco.MjData(m)
    d.qpos[robot.qpos_adr] = pose
    mujoco.mj_kinematics(m, d)
    g1, g2 = (int(np.flatnonzero(robot_geom_ids(robot) == g)[0]) if g != CLOUD_GEOM_ID else g for g in (g1, g2))
    if CLOUD_GEOM_ID in (g1, g2):
        other = g2 if g1 == CLOUD_GEOM_ID else g1
        return min((float(mujoco.mj_geomDistance(m, d, int(b), other, distmax, None)) for b in cloud_geom_ids(robot)),
                   default=distmax)
    return float(mujoco.mj_geomDistance(m, d, g1, g2, distmax, None))


@dataclass
class Disagreement:
    pose_index: int
    ours: bool
    mujoco: bool
    pairs: list[tuple[int, int]]        # geom pairs on which the two differ
    signed_distance: float              # MuJoCo's signed distance of the worst such pair (m)
    ours_min_distance: float            # our exact minimum signed distance at this pose (m)


@dataclass
class CrosscheckReport:
    """Our labels against MuJoCo's on the same poses."""

    n: int
    agreement: float                    # share of poses with the same collides label
    pair_agreement: float               # share of poses with the same set of colliding pairs
    confusion: np.ndarray               # [[both free, only MuJoCo collides], [only ours, both]]
    disagreements: list[Disagreement]
    mujoco_contacts: np.ndarray         # (B,) MuJoCo's ncon per pose
    ours: Labels = field(repr=False)
    reference: MujocoLabels = field(repr=False)

    @property
    def max_disagreement_distance(self) -> float:
        return max((abs(x.signed_distance) for x in self.disagreements), default=0.0)

    def summary(self) -> str:
        c = self.confusion
        lines = [
            f"{self.n} poses: label agreement {self.agreement:.4%}, pair-set agreement {self.pair_agreement:.4%}",
            f"confusion (rows ours free/colliding, cols MuJoCo free/colliding): {c.tolist()}",
            f"MuJoCo contacts per pose {self.mujoco_contacts.mean():.3f} "
            f"({self.mujoco_contacts[self.reference.collides].mean() if self.reference.collides.any() else 0:.2f} per colliding pose)",
            f"{len(self.disagreements)} label disagreements; largest |signed distance| {self.max_disagreement_distance:.2e} m",
        ]
        return "\n".join(lines)


def crosscheck(robot: Robot, poses: npt.ArrayLike, *, layout: Layout | None = None, margin: float = CLEARANCE,
               threads: int | None = None, progress: bool = True, executor: Executor | None = None,
               chunk: int = 2000) -> CrosscheckReport:
    """Labels ``poses`` with both our labeller and MuJoCo and compares them pose by pose.

    Every disagreement comes with MuJoCo's signed distance (``mj_geomDistance``) of the geom
    pair the two labellers disagree on; grazing contacts are |distance| < 1e-4 m.

    ``executor``: ``None`` (here) or an executor (:mod:`profrobot.executors`): MuJoCo's labels
    (the slow, single-threaded side) are then computed by its workers, ``chunk`` poses per task;
    the report is identical to the local one. ``layout``, ``margin``: as everywhere
    (:mod:`profrobot.robot.gate`), for both labellers.
    """
    robot = robot_at(robot, layout=layout, margin=margin, family=True)
    q = as_poses(robot, poses)
    ours = label_poses(robot, q, pairs=True, threads=threads)
    ref = mujoco_labels(robot, q, progress=progress, executor=executor, chunk=chunk)
    ours_pairs: list[set] = [set() for _ in range(len(q))]
    assert ours.colliding_pairs is not None   # asked for (pairs=True)
    for p, k in ours.colliding_pairs:
        g1, g2 = robot.pair_geoms[k]
        ours_pairs[p].add((int(min(g1, g2)), int(max(g1, g2))))
    same_pairs = np.array([a == b for a, b in zip(ours_pairs, ref.pairs)])
    confusion = np.zeros((2, 2), dtype=np.int64)
    np.add.at(confusion, (ours.collides.astype(int), ref.collides.astype(int)), 1)
    disagreements = []
    differ = np.flatnonzero(ours.collides != ref.collides)
    ours_dist = np.zeros(0)
    if len(differ):
        dist = label_poses(robot, q[differ], distance=True).min_distance
        assert dist is not None   # asked for (distance=True)
        ours_dist = dist
    for i, d_ours in zip(differ, ours_dist):
        diff = sorted(ours_pairs[i] ^ ref.pairs[i])
        dists = [mujoco_pair_distance(robot, q[i], a, b) for a, b in diff]
        worst = max(dists, key=abs) if dists else float("nan")
        disagreements.append(Disagreement(int(i), bool(ours.collides[i]), bool(ref.collides[i]), diff, worst,
                                          float(d_ours)))
    return CrosscheckReport(
        n=len(q), agreement=float((ours.collides == ref.collides).mean()),
        pair_agreement=float(same_pairs.mean()), confusion=confusion, disagreements=disagreements,
        mujoco_contacts=ref.ncon, ours=ours, reference=ref,
    )
