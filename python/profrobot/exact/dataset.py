"""Balanced pose datasets (the paper's resampling to about 1:1 collided:free), saved atomically
to one ``.npz`` file with poses, labels and metadata. Nothing is pickled."""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from .._core import __version__ as core_version
from ..robot import gate
from ..robot.equalities import EqualityMode
from ..errors import CorruptFileError, InputError, InputTypeError, MissingFileError
from ..files import atomic_path, check_format, check_robot, format_tag
from ..robot.angles import wrap
from .labels import check_threads, label_poses, sample_poses
from ..executors.progress import progress_bar
from ..executors.base import Executor
from ..robot.gate import CLEARANCE, Layout
from ..robot.robot import Robot

_LABELS = ("collides", "self_collides", "scene_collides", "n_pairs")


FORMAT_VERSION = 1  # the .npz layout: poses, the label arrays, metadata (JSON)

@dataclass
class Dataset:
    """Poses (N, K) in radians / metres and their exact labels, plus provenance metadata."""

    poses: np.ndarray
    collides: np.ndarray
    self_collides: np.ndarray
    scene_collides: np.ndarray
    n_pairs: np.ndarray
    metadata: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def collided_fraction(self) -> float:
        return float(self.collides.mean())

    def split(self, test_fraction: float = 0.1, seed: int = 0) -> tuple["Dataset", "Dataset"]:
        """A seeded (train, test) split, each keeping the metadata."""
        if not 0 < test_fraction < 1:
            raise InputError(f"test_fraction must be in (0, 1); got {test_fraction}")
        idx = np.random.default_rng(seed).permutation(len(self))
        n_test = max(1, int(round(len(self) * test_fraction)))
        return self.take(idx[n_test:]), self.take(idx[:n_test])

    @property
    def fingerprint(self) -> str | None:
        """The fingerprint of the robot the poses were labelled for (None if unknown)."""
        return self.metadata.get("robot_fingerprint")

    def concat(self, other: "Dataset") -> "Dataset":
        """These poses followed by ``other``'s, with their labels; this dataset's metadata."""
        return Dataset(np.concatenate([self.poses, other.poses]),
                       **{k: np.concatenate([getattr(self, k), getattr(other, k)]) for k in _LABELS},
                       metadata=dict(self.metadata))

    def take(self, idx: slice | Sequence[int] | npt.NDArray[np.integer] | npt.NDArray[np.bool_]) -> "Dataset":
        """The poses at ``idx`` (indices or a boolean mask) with their labels and this metadata."""
        return Dataset(self.poses[idx], **{k: getattr(self, k)[idx] for k in _LABELS}, metadata=dict(self.metadata))

    def save(self, path: str | os.PathLike) -> Path:
        """Writes one ``.npz`` atomically: a temporary file in the same folder, fsynced, then
        renamed over ``path``, so an interrupted save never leaves a half-written file."""
        path = os.fspath(path)
        if not path.endswith(".npz"):
            raise InputError(f"dataset files end in .npz; got {path!r}")
        metadata = {**self.metadata, "format": format_tag("dataset", FORMAT_VERSION)}
        with atomic_path(path) as tmp:
            np.savez(tmp, poses=self.poses, **{k: getattr(self, k) for k in _LABELS},
                     metadata=np.array(json.dumps(metadata)))
        return Path(path)

    @classmethod
    def load(cls, path: str | os.PathLike, robot: Robot | None = None) -> "Dataset":
        """Reads a file written by :meth:`save`; with ``robot``, refuses data for another robot
        (:class:`~profrobot.errors.RobotMismatchError`). A file that cannot be read as a dataset
        raises :class:`~profrobot.errors.CorruptFileError`; a missing one
        :class:`~profrobot.errors.MissingFileError` (a ``FileNotFoundError``)."""
        path = os.fspath(path)
        if not os.path.isfile(path):
            raise MissingFileError(f"no dataset file at {path!r}")
        with open(path, "rb") as f:
            head = f.read(4)
        if head != b"PK\x03\x04":   # .npz is a zip archive; anything else is not a dataset
            raise CorruptFileError(f"{path!r} is not a profrobot dataset: not an .npz archive "
                                   f"(it starts with {head!r}; Dataset.save writes one)")
        missing: list[str] = []
        try:
            with np.load(path, allow_pickle=False) as z:
                missing = [k for k in ("poses", "metadata", *_LABELS) if k not in z.files]
                if not missing:
                    data = {k: z[k] for k in ("poses", *_LABELS)}
                    metadata = json.loads(str(z["metadata"]))
        except (OSError, EOFError, ValueError, zipfile.BadZipFile) as e:  # JSONDecodeError is a ValueError
            raise CorruptFileError(f"{path!r} is corrupt or not a profrobot dataset: {e}") from e
        if missing:
            raise CorruptFileError(f"{path!r} is not a profrobot dataset: it lacks {', '.join(missing)}")
        if not isinstance(metadata, dict):
            raise CorruptFileError(f"{path!r} is corrupt: its metadata is not a JSON object")
        # files of earlier releases carry no tag: version 1's layout
        check_format(metadata.pop("format", None), "dataset", FORMAT_VERSION, repr(path), missing=1)
        ds = cls(**data, metadata=metadata)
        n = len(ds.poses)
        if ds.poses.ndim != 2 or any(getattr(ds, k).ndim != 1 or len(getattr(ds, k)) != n for k in _LABELS):
            raise CorruptFileError(f"{path!r} is corrupt: arrays of inconsistent shapes")
        if robot is not None:
            check_robot(metadata, robot, f"dataset {path!r}")
        return ds


def _round_seed(seed: int, round_index: int) -> int:
    """A distinct, reproducible 64-bit seed per sampling round."""
    return int(np.random.SeedSequence([seed, round_index]).generate_state(1, np.uint64)[0])


def sample_round(robot: Robot, seed: int, r: int, batch: int, threads: int | None,
                 equalities: EqualityMode) -> tuple[np.ndarray, ...]:
    """Sampling round ``r``: ``batch`` poses from the round's own seed and their labels,
    ``(poses, collides, self_collides, scene_collides, n_pairs)``. A pure function of its
    arguments (whatever ``threads``): make_dataset's chunk function, the same wherever an
    executor runs it."""
    q = sample_poses(robot, batch, _round_seed(seed, r), threads=threads, equalities=equalities)
    lab = label_poses(robot, q, threads=threads)
    return (q, *(getattr(lab, k) for k in _LABELS))


def make_dataset(robot: Robot, n: int, collided_fraction: float = 0.5, seed: int = 0, *, layout: Layout | None = None,
                 margin: float = CLEARANCE, batch: int = 100_000, max_samples: int | None = None,
                 progress: bool = True, threads: int | None = None, equalities: EqualityMode = "auto",
                 executor: Executor | None = None) -> Dataset:
    """``n`` poses with exact labels, resampled so that ``collided_fraction`` of them collide.

    Uniform poses are drawn in seeded rounds of ``batch`` and labelled; colliding and free poses
    are kept until each quota is full (the paper's balanced resampling), then shuffled. Raises
    if a quota cannot be met within ``max_samples`` draws (default ``200 * n``), naming the
    collision rate seen. Same seed, same dataset, whatever the thread count. ``equalities``
    chooses how coupled joints are sampled (see :func:`profrobot.sample_poses`).

    ``executor``: ``None`` (here, round by round) or an executor
    (:mod:`profrobot.executors`; e.g. a :class:`~profrobot.executors.RayExecutor`), whose
    workers draw and label the rounds (:func:`sample_round`, a pure function of ``seed`` and the
    round's index) while the quotas are filled here, in round order: the same dataset as the
    local run, whatever the number of workers (``threads`` is then the executor's ``threads``
    when it sets them). ``layout``, ``margin``: as everywhere (:mod:`profrobot.robot.gate`): a
    family's θ labelled at its layout, poses within ``margin`` of an obstacle labelled colliding.
    """
    from ..executors import check_executor

    robot = gate.robot_at(robot, layout=layout, margin=margin, family=True)
    n = gate.count("n", n)
    gate.memory("n", n, robot.njoint + 4)   # the poses and their labels
    collided_fraction = gate.finite("collided_fraction", collided_fraction)
    if not 0.0 <= collided_fraction <= 1.0:
        raise InputError(f"collided_fraction must be in [0, 1]; got {collided_fraction}")
    batch = gate.count("batch", batch)
    threads = check_threads(threads)
    executor = check_executor(executor)
    want_coll = int(round(n * collided_fraction))
    want = {True: want_coll, False: n - want_coll}
    kept: dict[bool, list[tuple[np.ndarray, ...]]] = {True: [], False: []}  # (poses, *labels) per round
    have = {True: 0, False: 0}
    drawn = seen_colliding = 0
    max_samples = max_samples or 200 * n
    max_rounds = -(-max_samples // batch)

    def rounds_needed() -> int:
        """More rounds the quotas still need, at the collision rate seen so far (at least the
        ``n`` draws left to keep, before any round came back)."""
        if drawn == 0:
            return -(-n // batch)
        rate = {True: seen_colliding / drawn, False: 1 - seen_colliding / drawn}
        need = [-(-(want[c] - have[c]) // max(1, int(batch * rate[c]))) for c in (True, False) if have[c] < want[c]]
        return max(need, default=1)

    round_threads = threads if executor.threads is None else executor.threads
    stream = executor.ordered(sample_round, lambda r: (int(seed), r, int(batch), round_threads, equalities),
                              max_rounds, rounds_needed, robot=robot)
    rounds: Iterator[tuple[np.ndarray, ...]] = (value for _, value in stream)
    bar = progress_bar(n, desc=f"dataset {robot.name}", unit="pose", progress=progress)
    try:
        while have[True] < want[True] or have[False] < want[False]:
            if drawn >= max_samples:
                raise InputError(f"could not fill the quotas for {robot.name} after {drawn} samples "
                                     f"(collision rate {seen_colliding / drawn:.3%}); lower collided_fraction "
                                     "or raise max_samples")
            q, *lab = next(rounds)
            collides = lab[0]
            drawn += batch
            seen_colliding += int(collides.sum())
            for c in (True, False):
                idx = np.flatnonzero(collides == c)[: want[c] - have[c]]
                if len(idx):
                    kept[c].append((q[idx], *(x[idx] for x in lab)))
                    have[c] += len(idx)
                    bar.update(len(idx))
    finally:
        bar.close()
        stream.close()  # cancels the rounds no longer needed (in flight on workers)
    parts = kept[True] + kept[False]
    order = np.random.default_rng(seed).permutation(n)
    poses, *labels = (np.concatenate(column)[order] for column in zip(*parts))
    from .._core import __version__

    metadata = dict(robot=robot.name, robot_fingerprint=robot.fingerprint, joint_names=robot.joint_names,
                    seed=int(seed), equalities=equalities, collided_fraction=float(collided_fraction), samples_drawn=int(drawn),
                    uniform_collision_rate=seen_colliding / drawn, library_version=__version__,
                    core_version=core_version)
    return Dataset(poses, **dict(zip(_LABELS, labels)), metadata=metadata)


def boundary_dataset(robot: Robot, n: int, seed: int = 0, *, spread: float = 0.02, bisections: int = 12,
                     batch: int = 100_000, threads: int | None = None) -> Dataset:
    """``n`` poses near the collision boundary, with exact labels (about half of them collide).

    Each round draws uniform poses, pairs colliding with free ones, and bisects the segment
    between them (SO(2) for continuous hinges) ``bisections`` times with the exact labeller to a
    boundary point; each point is then moved by Gaussian noise of ``spread`` × the joint's range
    per joint (continuous hinges: of 2π), clipped to the limits and put back on the robot's
    couplings, and labelled exactly. So the poses are where a field's sign is hardest to get
    right. Same seed, same poses, whatever the thread count.
    """
    if not isinstance(robot, Robot):
        raise InputTypeError(f"expected a profrobot.Robot; got {type(robot).__name__}")
    n = gate.count("n", n)
    gate.memory("n", n, robot.njoint + 4)
    spread = gate.finite("spread", spread)
    if spread <= 0:
        raise InputError(f"spread must be > 0; got {spread}")
    threads = check_threads(threads)
    lim = robot.joint_limits
    cont = robot.continuous
    width = np.where(cont, 2 * np.pi, lim[:, 1] - lim[:, 0])
    kept: list[np.ndarray] = []
    have, r = 0, 0
    while have < n:
        if r > 64 and have == 0:
            raise InputError(f"{robot.name}: no boundary poses after {r} rounds (is there any collision, or any free pose?)")
        rng = np.random.default_rng(_round_seed(seed, 0xB0 + r))
        q = sample_poses(robot, batch, _round_seed(seed, 0xB000 + r), threads=threads)
        c = robot.core.collides(q, threads=threads)
        coll, free = rng.permutation(np.flatnonzero(c)), rng.permutation(np.flatnonzero(~c))
        m = min(len(coll), len(free))
        r += 1
        if m == 0:
            continue
        a, b = q[free[:m]], q[coll[:m]]
        step = b - a
        step[:, cont] = wrap(step[:, cont])          # continuous hinges the short way round

        def at(t: np.ndarray, a: np.ndarray = a, step: np.ndarray = step) -> np.ndarray:
            x = a + t[:, None] * step
            x[:, cont] = wrap(x[:, cont])
            robot.couplings.apply(x)
            return x

        lo, hi = np.zeros(m), np.ones(m)             # lo free, hi colliding (exact labels)
        for _ in range(bisections):
            mid = 0.5 * (lo + hi)
            hit = robot.core.collides(at(mid), threads=threads)
            hi = np.where(hit, mid, hi)
            lo = np.where(hit, lo, mid)
        x = at(hi) + rng.standard_normal((m, robot.njoint)) * (spread * width)
        x[:, cont] = wrap(x[:, cont])
        x[:, ~cont] = np.clip(x[:, ~cont], lim[~cont, 0], lim[~cont, 1])
        robot.couplings.apply(x)
        x = x[robot.feasible(x)] if robot.couplings else x
        kept.append(x[: n - have])
        have += len(kept[-1])
    poses = np.concatenate(kept)
    lab = label_poses(robot, poses, threads=threads)
    metadata = dict(robot=robot.name, robot_fingerprint=robot.fingerprint, joint_names=robot.joint_names,
                    seed=int(seed), boundary=dict(spread=float(spread), bisections=int(bisections)),
                    library_version=core_version, core_version=core_version)
    return Dataset(poses, **{k: getattr(lab, k) for k in _LABELS}, metadata=metadata)
